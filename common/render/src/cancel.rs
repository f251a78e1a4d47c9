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
    /// While set, a check waits (the render holds its place, using no CPU) until it clears
    /// or the token is cancelled: a render node's master gone silent, maybe only paused.
    hold: Option<Arc<AtomicBool>>,
}

/// How often a held render looks again whether it may go on.
const HOLD_POLL: std::time::Duration = std::time::Duration::from_millis(10);

impl Cancel {
    /// A token nobody has cancelled.
    pub fn new() -> Self {
        Cancel {
            flags: vec![Arc::default()],
            hold: None,
        }
    }

    /// A token cancelled by its own [`Cancel::cancel`] or by this one's.
    pub fn child(&self) -> Cancel {
        let mut flags = vec![Arc::default()];
        flags.extend(self.flags.iter().cloned());
        Cancel {
            flags,
            hold: self.hold.clone(),
        }
    }

    /// This token, whose renders also stop and wait where they are while `hold` is set, and
    /// go on when it clears (or end, if cancelled meanwhile).
    ///
    /// ```
    /// use std::sync::atomic::{AtomicBool, Ordering};
    /// use std::sync::Arc;
    /// use tessera_render::Cancel;
    ///
    /// let hold = Arc::new(AtomicBool::new(true));
    /// let token = Cancel::new().held_while(hold.clone());
    /// let waiter = std::thread::spawn({
    ///     let token = token.clone();
    ///     move || token.is_cancelled()
    /// });
    /// hold.store(false, Ordering::Relaxed);
    /// assert!(!waiter.join().unwrap(), "released, it goes on");
    /// ```
    pub fn held_while(mut self, hold: Arc<AtomicBool>) -> Cancel {
        self.hold = Some(hold);
        self
    }

    /// Stops every render holding this token or one of its children, at their next check.
    pub fn cancel(&self) {
        if let Some(own) = self.flags.first() {
            own.store(true, Ordering::Relaxed);
        }
    }

    /// Whether this token or an ancestor is cancelled: a relaxed load per level (one or
    /// two) and one of the hold, cheap enough to check once per sample of a packet. While
    /// held, it waits until released (false) or cancelled (true).
    #[inline]
    pub fn is_cancelled(&self) -> bool {
        loop {
            if self.flags.iter().any(|f| f.load(Ordering::Relaxed)) {
                return true;
            }
            match &self.hold {
                Some(hold) if hold.load(Ordering::Relaxed) => std::thread::sleep(HOLD_POLL),
                _ => return false,
            }
        }
    }
}

impl Default for Cancel {
    fn default() -> Self {
        Cancel::new()
    }
}
