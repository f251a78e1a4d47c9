//! What running nodes tell an operator's console: a display's frame shrunk (bounded on
//! arrival like every message) and a render node's figures so far.

use crate::FrameId;
use serde::{Deserialize, Serialize};

/// Largest shrink factor of a thumbnail.
pub const MAX_THUMBNAIL_FACTOR: u32 = 256;

/// Most bytes of pixels a thumbnail carries: well under a control message's bound, and small
/// enough not to hold a display's other messages up for long.
pub const MAX_THUMBNAIL_BYTES: usize = 512 * 1024;

/// A display's frame, shrunk for the operator's console (see [`crate::ToNode::SendThumbnail`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Thumbnail {
    /// The frame it shows; 0 with no pixels before the first present.
    pub frame: FrameId,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// RGB8 rows, top down: `width * height * 3` bytes, at most [`MAX_THUMBNAIL_BYTES`].
    pub rgb: Vec<u8>,
}

#[derive(Deserialize)]
struct ThumbnailRaw {
    frame: FrameId,
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl<'de> Deserialize<'de> for Thumbnail {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let raw = ThumbnailRaw::deserialize(d)?;
        let bytes = raw.width as u64 * raw.height as u64 * 3;
        if bytes != raw.rgb.len() as u64 || raw.rgb.len() > MAX_THUMBNAIL_BYTES {
            return Err(serde::de::Error::custom(format!(
                "a {}x{} thumbnail with {} bytes (at most {MAX_THUMBNAIL_BYTES})",
                raw.width,
                raw.height,
                raw.rgb.len()
            )));
        }
        Ok(Thumbnail {
            frame: raw.frame,
            width: raw.width,
            height: raw.height,
            rgb: raw.rgb,
        })
    }
}

/// How often a render node sends its [`Progress`].
pub const PROGRESS_INTERVAL: std::time::Duration = std::time::Duration::from_secs(1);

/// A render node's figures so far (see [`crate::FromNode::Progress`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    /// Rays traced since the node joined.
    pub rays: u64,
    /// Its peak resident memory, bytes (0 where the system does not say).
    pub max_rss_bytes: u64,
    /// Reads of a shared scene that missed this node's memory; `None` for replicated data.
    pub dsm_misses: Option<u64>,
}
