//! Deserializing through a validating constructor, keeping the reason for a refusal.
//!
//! Every wire type with an invariant is read as its plain fields and then checked by the same
//! `TryFrom` its callers use, so a value that breaks an invariant never exists (the pattern of
//! `#[serde(try_from = ...)]`). postcard drops the text of a custom error, and "malformed
//! message" alone would hide *what* was wrong, so the reason is also kept here, per thread,
//! for `tessera_protocol::codec::decode` to report.

use serde::{de::Error as _, Deserialize, Deserializer};
use std::cell::RefCell;
use std::fmt::Display;

thread_local! {
    static REFUSAL: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Deserializes `Raw` and turns it into `T` with `T::try_from`, recording why it was refused.
pub fn deserialize<'de, D, Raw, T>(deserializer: D) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
    Raw: Deserialize<'de>,
    T: TryFrom<Raw>,
    T::Error: Display,
{
    let raw = Raw::deserialize(deserializer)?;
    T::try_from(raw).map_err(|e| {
        let why = e.to_string();
        REFUSAL.with(|r| *r.borrow_mut() = Some(why.clone()));
        D::Error::custom(why)
    })
}

/// Forgets an earlier refusal, before a new message is decoded.
pub fn clear() {
    REFUSAL.with(|r| r.borrow_mut().take());
}

/// Why the last value deserialized on this thread was refused, if one was.
pub fn take_refusal() -> Option<String> {
    REFUSAL.with(|r| r.borrow_mut().take())
}

/// Decodes postcard `bytes` as the codec does, for this crate's tests (the codec itself is
/// `tessera-protocol`'s): the refusal's reason if a check refused the value.
#[cfg(test)]
pub(crate) fn decode_for_test<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T, Refusal> {
    clear();
    postcard::from_bytes(bytes).map_err(|e| Refusal(take_refusal().unwrap_or(e.to_string())))
}

/// Why a test's value was refused.
#[cfg(test)]
#[derive(Debug)]
pub(crate) struct Refusal(pub String);

#[cfg(test)]
impl Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
