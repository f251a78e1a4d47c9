//! What the master makes of silence: a suspected node is logged and kept, a dead one closed,
//! and silence in a time the master itself did not run is credited to every node.

use super::*;
use crate::balance::Output;

/// Lateness of the master's own wake-up that is the scheduler's ordinary noise, not a pause.
const PAUSE_TOLERANCE: Duration = Duration::from_millis(25);

impl Master {
    /// Before any input at `now`: if the master wakes later than it asked to (its process
    /// was stopped, or starved of CPU), nobody could be heard in between, so that time counts
    /// against no node. Computed from what the coordinator asked before this input, so
    /// whichever input comes first after the pause (a queued message or the timer) sees it.
    pub(super) fn credit_own_pause(&mut self, now: Now) {
        if self.phase != Phase::Running {
            return;
        }
        let Some(due) = self.coordinator.poll_timeout() else {
            return;
        };
        let late = now.instant.saturating_duration_since(due);
        if late <= PAUSE_TOLERANCE {
            return;
        }
        self.coordinator.credit_blind_time(late, now.instant);
        self.record.master_pauses += 1;
        self.record.longest_master_pause = self.record.longest_master_pause.max(late);
        if late >= self.cfg.balance.node_deadline {
            tracing::warn!(
                "the master did not run for {} ms (stopped, or starved of CPU); silence in that time counts against no node",
                late.as_millis()
            );
        }
    }

    /// A suspected node is logged and kept; a suspected node that spoke again is back.
    pub(super) fn suspicion(&mut self, out: &Output) {
        let who = |m: &Master, peer: Option<&PeerId>| {
            peer.map_or_else(|| "a node".to_string(), |&p| m.describe(p))
        };
        match *out {
            Output::RenderSuspected { node, silent } => {
                self.record.suspicions += 1;
                tracing::warn!(
                    "{} silent for {} ms: suspected; its tiles are copied to the others, and it stays in the run",
                    who(self, self.renders.get(&node)),
                    silent.as_millis()
                );
            }
            Output::DisplaySuspected { display: d, silent } => {
                self.record.suspicions += 1;
                tracing::warn!(
                    "{} silent for {} ms: suspected; the barrier waits for it",
                    who(self, self.displays.get(&d)),
                    silent.as_millis()
                );
            }
            Output::RenderBack { node, silent } => tracing::info!(
                "{} is back after {} ms of silence",
                who(self, self.renders.get(&node)),
                silent.as_millis()
            ),
            Output::DisplayBack { display: d, silent } => tracing::info!(
                "{} is back after {} ms of silence",
                who(self, self.displays.get(&d)),
                silent.as_millis()
            ),
            _ => {}
        }
    }

    /// Closes the connection of a peer the coordinator found dead by its silence, and drops
    /// it as if it had left.
    pub(super) fn drop_silent(&mut self, peer: PeerId, silent: Duration, now: Now) {
        let death = self.cfg.balance.death;
        let reason = format!(
            "silent for {} ms, past what its heartbeats allow (phi {} with a {} ms acceptable pause)",
            silent.as_millis(),
            death.phi_threshold,
            death.acceptable_pause.as_millis()
        );
        self.close_and_drop(peer, CloseReason::SilentPastDeadline, now, &reason);
    }

    /// The run is over: render nodes still suspected are not waited for (a dead one would
    /// hold the end for the whole stats wait); they count as lost, and say why. A suspected
    /// display is waited for: under `--display-loss stop` dropping it would fail a run that
    /// completed.
    pub(super) fn drop_suspected_at_the_end(&mut self, now: Now) {
        let peers: Vec<PeerId> = self
            .coordinator
            .suspected_render_nodes()
            .filter_map(|n| self.renders.get(&n).copied())
            .collect();
        let reason = "still silent (suspected) when the run ended";
        for peer in peers {
            self.close_and_drop(peer, CloseReason::SilentPastDeadline, now, reason);
        }
    }
}
