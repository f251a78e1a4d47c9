//! Tracing a shared scene's packets so that a miss never idles a core (Pharr et al. 1997,
//! "Rendering complex scenes with memory-coherent ray tracing": rays wait in queues for their
//! data, not threads).
//!
//! A packet is traced with a reader that parks its misses: a block that is neither held, nor
//! cached, nor pinned is asked for and read as a stand-in no ray enters or hits, and the trace
//! runs to its end. If it missed anything, its result is dropped and the packet is set aside
//! with the blocks it waits for; the thread goes on with the next packet. Once every block a
//! set-aside packet waits for has landed, the packet is traced again from its start with those
//! blocks pinned (kept alive by the packet, whatever the cache does meanwhile), so each trace
//! gets further than the one before, and its last trace read only real blocks: its pixels are
//! the replicated ones, bit for bit. A thread waits only when every packet left is waiting for
//! a block; that wait is counted as every pool thread's idle time.
//!
//! Tracing again from the start, rather than resuming where the miss was, spends the part of
//! the trace before the miss twice; against a remote read's hundreds of microseconds that is a
//! few microseconds of resident reads, and it keeps the shading code free of suspended state.

use crate::cancel::Cancel;
use crate::dsm::{DsmTree, Landing, PinLimits};
use crate::tracer::{Carried, Tracer};
use crate::PreparedScene;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tessera_core::dsm::BlockId;

/// Traces of one packet set aside before it is traced waiting for each block as it comes
/// (every trace gets further, so this bounds only a pathological case: a packet whose rays
/// read more blocks than this, one after another).
const MOST_PARKS: u32 = 64;

/// How long a thread sleeps at most before it looks at the set-aside packets again (a landing
/// wakes it at once; this bounds a wake-up that went astray, and cancellation).
const LOOK_AGAIN: Duration = Duration::from_millis(20);

/// A packet to trace: its index, what its earlier traces left it, and how often it was set
/// aside.
struct Attempt {
    index: usize,
    carried: Carried,
    parks: u32,
    /// The blocks it holds of the parked packets' budget while set aside.
    reserved: Vec<BlockId>,
}

/// The bounds on what set-aside packets keep, and what they keep now.
struct PinBudget {
    limits: PinLimits,
    block_bytes: usize,
    /// The blocks the packets set aside keep or wait for, each with how many do: packets of
    /// one tile share most of theirs, so the memory is that of the distinct blocks.
    held: Mutex<HashMap<BlockId, u32>>,
}

impl PinBudget {
    /// Reserves room for a packet keeping `carried` and waiting for `missed`: the blocks
    /// reserved, or `None` if there is no room.
    fn reserve(&self, carried: &Carried, missed: &[(BlockId, Landing)]) -> Option<Vec<BlockId>> {
        if carried.pinned_bytes() >= self.limits.per_packet {
            return None;
        }
        let mut ids: Vec<BlockId> = carried.pins.iter().map(|(k, _)| *k).collect();
        ids.extend(missed.iter().map(|(k, _)| *k));
        ids.sort_unstable();
        ids.dedup();
        let mut held = self.held.lock().unwrap_or_else(|e| e.into_inner());
        let new = ids.iter().filter(|k| !held.contains_key(k)).count();
        if (held.len() + new).saturating_mul(self.block_bytes) > self.limits.parked {
            return None;
        }
        for &k in &ids {
            *held.entry(k).or_default() += 1;
        }
        Some(ids)
    }

    /// A packet set aside is traced again: what it reserved is free.
    fn release(&self, ids: &[BlockId]) {
        let mut held = self.held.lock().unwrap_or_else(|e| e.into_inner());
        for k in ids {
            if let Some(n) = held.get_mut(k) {
                *n -= 1;
                if *n == 0 {
                    held.remove(k);
                }
            }
        }
    }
}

/// A packet set aside for the blocks it missed.
struct Parked {
    attempt: Attempt,
    missed: Vec<(BlockId, Landing)>,
}

impl Parked {
    fn ready(&self) -> bool {
        self.missed.iter().all(|(_, l)| l.block().is_some())
    }

    /// The packet again, the blocks it waited for pinned (and cached, for other packets).
    fn resume(self, tree: &DsmTree) -> Attempt {
        let mut attempt = self.attempt;
        for (k, landing) in self.missed {
            if let Some(block) = landing.block() {
                tree.cache_landed(k, block);
                attempt.carried.pins.push((k, block.clone()));
            }
        }
        attempt
    }
}

/// `trace(tracer, i)` for every `i` in `0..count`, in parallel on the current rayon pool, in
/// index order; `None` if `cancel` was cancelled first. On a scene in shared memory a packet
/// that misses a block is set aside and traced again once it has landed (see the module doc):
/// `trace` must be a pure function of `i` and the scene.
pub(crate) fn trace_all<T: Send>(
    scene: &PreparedScene,
    count: usize,
    cancel: &Cancel,
    trace: impl Fn(&mut Tracer<'_>, usize) -> T + Sync,
) -> Option<Vec<T>> {
    let Some(tree) = scene.shared.as_ref().filter(|t| t.parks_misses()) else {
        let all = (0..count)
            .into_par_iter()
            .map_init(|| scene.tracer(), |tracer, i| trace(tracer, i))
            .collect();
        return Some(all);
    };
    let mut done: Vec<Option<T>> = (0..count).map(|_| None).collect();
    let mut todo: Vec<Attempt> = (0..count)
        .map(|index| Attempt {
            index,
            carried: Carried::default(),
            parks: 0,
            reserved: Vec::new(),
        })
        .collect();
    let mut parked: Vec<Parked> = Vec::new();
    let budget = PinBudget {
        limits: tree.pin_limits(),
        block_bytes: tree.layout().block_bytes as usize,
        held: Mutex::new(HashMap::new()),
    };
    loop {
        let traced: Vec<Result<(usize, T), Box<Parked>>> = todo
            .into_par_iter()
            .map_init(
                || scene.tracer(),
                |tracer, a| trace_once(tracer, a, (&trace, &budget)),
            )
            .collect();
        for t in traced {
            match t {
                Ok((i, value)) => done[i] = Some(value),
                Err(p) => parked.push(*p),
            }
        }
        if parked.is_empty() {
            break;
        }
        todo = wait_for_ready(tree, &mut parked, cancel)?;
        for attempt in &mut todo {
            budget.release(&std::mem::take(&mut attempt.reserved));
        }
    }
    done.into_iter().collect()
}

/// Traces one attempt: its value, or the attempt set aside with what it missed.
fn trace_once<T>(
    tracer: &mut Tracer<'_>,
    attempt: Attempt,
    (trace, budget): (&impl Fn(&mut Tracer<'_>, usize) -> T, &PinBudget),
) -> Result<(usize, T), Box<Parked>> {
    let Attempt {
        index,
        carried,
        parks,
        ..
    } = attempt;
    tracer.park_misses(parks < MOST_PARKS, carried);
    let value = trace(tracer, index);
    let (missed, carried) = tracer.take_missed();
    tracer.park_misses(false, Carried::default());
    if missed.is_empty() {
        return Ok((index, value));
    }
    let Some(reserved) = budget.reserve(&carried, &missed) else {
        // No room to set it aside: traced again at once, waiting for each block it misses.
        tracer.park_misses(false, carried);
        let value = trace(tracer, index);
        let _ = tracer.take_missed();
        tracer.park_misses(false, Carried::default());
        return Ok((index, value));
    };
    Err(Box::new(Parked {
        attempt: Attempt {
            index,
            carried,
            parks: parks + 1,
            reserved,
        },
        missed,
    }))
}

/// The set-aside packets whose blocks have all landed, taken out of `parked`, waiting for a
/// landing while there are none (counted as idle time of every pool thread); all of them, to
/// be traced waiting, once nothing will land any more. `None` if `cancel` was cancelled.
fn wait_for_ready(
    tree: &DsmTree,
    parked: &mut Vec<Parked>,
    cancel: &Cancel,
) -> Option<Vec<Attempt>> {
    tree.count_parked(parked.len() as u64);
    let fetch = tree.fetcher();
    loop {
        let seen = fetch.landings();
        let (ready, waiting): (Vec<Parked>, Vec<Parked>) =
            std::mem::take(parked).into_iter().partition(Parked::ready);
        *parked = waiting;
        if !ready.is_empty() {
            return Some(ready.into_iter().map(|p| p.resume(tree)).collect());
        }
        if cancel.is_cancelled() {
            return None;
        }
        let t0 = Instant::now();
        let landing_goes_on = fetch.wait_for_landing(seen, LOOK_AGAIN);
        tree.count_idle(t0.elapsed() * rayon::current_num_threads() as u32);
        if !landing_goes_on {
            return Some(
                std::mem::take(parked)
                    .into_iter()
                    .map(|p| Attempt {
                        parks: MOST_PARKS,
                        ..p.resume(tree)
                    })
                    .collect(),
            );
        }
    }
}
