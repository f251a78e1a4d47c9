//! Stopping a render part-way: a flag the render threads read between samples of a packet.
//!
//! A frame at a runaway quality (`--spp 4096 --ao 63` is some 16 million rays per 8×8
//! packet, seconds of one core) must still stop at once when its master is gone, the node
//! shuts down, or the frame is no longer wanted. Tokens nest: a batch's token is a child of
//! its session's, so cancelling the session stops every batch and cancelling one batch stops
//! only it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A flag that stops the renders holding it; cheap to clone and to check.
///
/// # Examples
///
/// ```
/// use tessera_render::Cancel;
///
/// let session = Cancel::new();
/// let (a, b) = (session.child(), session.child());
/// a.cancel();
/// assert!(a.is_cancelled() && !b.is_cancelled() && !session.is_cancelled());
/// session.cancel();
/// assert!(b.is_cancelled());
/// ```
#[derive(Clone, Debug)]
pub struct Cancel {
    /// This token's flag first, then its ancestors'.
    flags: Vec<Arc<AtomicBool>>,
}

impl Cancel {
    /// A token nobody has cancelled.
    pub fn new() -> Self {
        Cancel {
            flags: vec![Arc::default()],
        }
    }

    /// A token cancelled by its own [`Cancel::cancel`] or by this one's.
    pub fn child(&self) -> Cancel {
        let mut flags = vec![Arc::default()];
        flags.extend(self.flags.iter().cloned());
        Cancel { flags }
    }

    /// Stops every render holding this token or one of its children, at their next check.
    pub fn cancel(&self) {
        if let Some(own) = self.flags.first() {
            own.store(true, Ordering::Relaxed);
        }
    }

    /// Whether this token or an ancestor is cancelled: a relaxed load per level (one or
    /// two), cheap enough to check once per sample of a packet.
    #[inline]
    pub fn is_cancelled(&self) -> bool {
        self.flags.iter().any(|f| f.load(Ordering::Relaxed))
    }
}

impl Default for Cancel {
    fn default() -> Self {
        Cancel::new()
    }
}
