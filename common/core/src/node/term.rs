//! Which master a node follows: the one of the highest term it has seen. A standby that took
//! the wall over has a term one more than the master before it (see
//! `tessera_core::master::standby`); an old primary that comes back, with its old term, is
//! refused, and told so, so that it steps down.

use tessera_protocol::FromNode;

/// The highest master term a node has seen, over its reconnections to the list of masters
/// (`--master A,B`). Keep one per node process, not per connection.
///
/// # Examples
///
/// ```
/// use tessera_core::node::term::MasterTerm;
///
/// let mut term = MasterTerm::default();
/// assert!(term.admit(0).is_ok(), "the first master");
/// assert!(term.admit(1).is_ok(), "the standby that took over");
/// let stale = term.admit(0).unwrap_err();
/// assert_eq!(stale.seen, 1);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MasterTerm {
    highest: Option<u64>,
}

/// A master's welcome carried a term below one the node has followed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the master's term {offered} is older than term {seen}, which this node follows: it is a stale master")]
pub struct StaleMaster {
    /// The term the master's welcome carried.
    pub offered: u64,
    /// The highest term the node has seen.
    pub seen: u64,
}

impl StaleMaster {
    /// What the node sends the stale master before it closes the connection, so that it
    /// steps down.
    pub fn message(&self) -> FromNode {
        FromNode::StaleMaster { seen: self.seen }
    }
}

impl MasterTerm {
    /// The highest term seen, if any master welcomed the node yet.
    pub fn highest(&self) -> Option<u64> {
        self.highest
    }

    /// A master welcomed the node with `term`: it is followed if its term is at least the
    /// highest seen (the same master again, or a newer one), and the highest is raised.
    ///
    /// # Errors
    /// [`StaleMaster`]: its term is below the highest seen; the node sends
    /// [`StaleMaster::message`], closes the connection and tries the next master.
    pub fn admit(&mut self, term: u64) -> Result<(), StaleMaster> {
        match self.highest {
            Some(seen) if term < seen => Err(StaleMaster {
                offered: term,
                seen,
            }),
            _ => {
                self.highest = Some(term);
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_node_refuses_a_lower_term_and_follows_an_equal_or_higher_one() {
        let mut term = MasterTerm::default();
        assert_eq!(term.highest(), None);
        term.admit(2).unwrap();
        term.admit(2).unwrap();
        assert_eq!(term.highest(), Some(2));
        let stale = term.admit(1).unwrap_err();
        assert_eq!(
            stale,
            StaleMaster {
                offered: 1,
                seen: 2
            }
        );
        assert_eq!(stale.message(), FromNode::StaleMaster { seen: 2 });
        assert_eq!(term.highest(), Some(2), "a refusal lowers nothing");
        term.admit(5).unwrap();
        assert!(term.admit(4).is_err() && term.admit(2).is_err());
        assert_eq!(term.highest(), Some(5));
    }
}
