//! The wait before the first frame, in two parts: nodes have the join timeout to join; once
//! every node the wall needs has joined, they have the load timeout to load the scene and say
//! they are ready. A big scene may load for minutes: render nodes say how far they are, and the
//! master's log says so, rather than a join timeout cutting a load short.

use super::*;
use tessera_protocol::LoadStep;

/// How often at most a render node's loading is logged while it stays at the same step (it
/// reports every [`tessera_protocol::LOAD_REPORT_INTERVAL`]).
const LOG_EVERY_S: u32 = 10;

/// Whether every node has joined, and what loading render nodes said last.
#[derive(Default)]
pub(super) struct Loading {
    /// When every node the wall needs had joined: the load timeout runs from then.
    all_joined: Option<Instant>,
    /// What each render node said last of its loading.
    said: BTreeMap<RenderNodeId, Said>,
}

/// A render node's last word on its loading.
struct Said {
    step: LoadStep,
    elapsed_s: u32,
    /// The step and seconds of the line last logged, if one was.
    logged: Option<(LoadStep, u32)>,
}

impl Master {
    /// Once every node the wall needs has joined, before the first frame: from now on the
    /// nodes have the load timeout to be ready, and the log says who is still loading.
    pub(super) fn load_if_all_joined(&mut self, now: Now) {
        let joining = matches!(self.phase, Phase::Joining { .. });
        if !joining || self.loading.all_joined.is_some() || !self.all_joined() {
            return;
        }
        self.loading.all_joined = Some(now.instant);
        self.phase = Phase::Joining {
            deadline: now.instant + self.cfg.load_timeout,
        };
        if !self.all_ready() {
            tracing::info!(
                "every node joined; waiting at most {} s (--load-timeout) for them to load the scene ({})",
                self.cfg.load_timeout.as_secs(),
                self.missing_summary()
            );
        }
    }

    /// Every display and as many render nodes as the wall waits for have joined.
    fn all_joined(&self) -> bool {
        self.displays.len() == self.cfg.wall.display_count() as usize
            && self.renders.len() >= self.cfg.render_nodes as usize
    }

    /// The wait before the first frame is over: a join timeout if some node never joined, a
    /// load timeout if every node joined but some were not ready in time.
    pub(super) fn joining_timed_out(&mut self) {
        let missing = self.missing_summary();
        let error = match self.loading.all_joined {
            None => RunError::JoinTimeout {
                waited: self.cfg.join_timeout,
                missing,
            },
            Some(_) => RunError::LoadTimeout {
                waited: self.cfg.load_timeout,
                missing: format!("{missing}{}", self.loading_summary()),
            },
        };
        self.fail(error);
    }

    /// A render node says how far its loading is: logged when its step changes, and every
    /// [`LOG_EVERY_S`] seconds while it stays.
    pub(super) fn note_loading(
        &mut self,
        peer: PeerId,
        node: RenderNodeId,
        step: LoadStep,
        elapsed_s: u32,
    ) {
        let said = self.loading.said.entry(node).or_insert(Said {
            step,
            elapsed_s,
            logged: None,
        });
        (said.step, said.elapsed_s) = (step, elapsed_s);
        let due = said
            .logged
            .is_none_or(|(was, at)| was != step || elapsed_s >= at + LOG_EVERY_S);
        if due {
            said.logged = Some((step, elapsed_s));
            let who = self.describe(peer);
            tracing::info!("{who}: loading the scene: {step}, {elapsed_s} s so far");
        }
    }

    /// What the render nodes not ready yet said last of their loading, as `; render node 2:
    /// reading the scene (40 s)`; empty if none said anything.
    fn loading_summary(&self) -> String {
        let mut text = String::new();
        for (node, said) in &self.loading.said {
            let ready = self
                .renders
                .get(node)
                .and_then(|p| self.peers.get(p))
                .is_some_and(|p| p.ready);
            if !ready {
                let (id, step, s) = (node.0, said.step, said.elapsed_s);
                text.push_str(&format!("; render node {id}: {step} ({s} s)"));
            }
        }
        text
    }
}
