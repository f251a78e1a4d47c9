use super::*;
use proptest::prelude::*;

const MS: Duration = Duration::from_millis(1);

fn fetcher(total: u32, ranks: u32, rank: u32, replicas: u32, batch_max: usize) -> Fetcher {
    let residency = Residency::new(total, ranks, Some(rank), replicas).unwrap();
    let config = FetchConfig {
        batch_max,
        timeout: 10 * MS,
    };
    Fetcher::new(residency, config)
}

fn drain(f: &mut Fetcher) -> Vec<FetchOutput> {
    std::iter::from_fn(|| f.poll_output()).collect()
}

fn request(peer: u32, blocks: &[BlockId]) -> FetchOutput {
    FetchOutput::Request {
        peer,
        blocks: blocks.to_vec(),
        ahead: false,
    }
}

#[test]
fn a_block_missed_by_many_threads_is_asked_once_and_prefetches_are_counted_apart() {
    let mut f = fetcher(16, 4, 0, 1, 64);
    let now = Instant::now();
    for _ in 0..3 {
        f.handle_miss(6, now);
    }
    f.handle_prefetch(6, now);
    f.handle_prefetch(7, now);
    assert_eq!(f.in_flight(), 0, "nothing leaves before the flush");
    f.flush(now);
    // Block 7 was only prefetched.
    let ahead_7 = FetchOutput::Request {
        peer: 3,
        blocks: vec![7],
        ahead: true,
    };
    assert_eq!(drain(&mut f), [request(2, &[6]), ahead_7]);
    // Wanted while in flight: still not asked again.
    f.handle_miss(6, now);
    f.flush(now);
    assert_eq!(drain(&mut f), []);
    let stats = f.stats();
    assert_eq!((stats.misses, stats.prefetches), (4, 2));
    assert_eq!((stats.requests, stats.blocks_requested), (2, 2));
    assert_eq!(f.in_flight(), 2);
}

#[test]
fn a_flush_sends_one_request_per_peer_split_at_batch_max() {
    let mut f = fetcher(400, 4, 0, 1, 64);
    let now = Instant::now();
    // 100 blocks of node 1, 3 of node 2.
    let ones: Vec<BlockId> = (0..100).map(|i| 4 * i + 1).collect();
    for &k in ones.iter().chain(&[2, 6, 10]) {
        f.handle_miss(k, now);
    }
    f.flush(now);
    assert_eq!(
        drain(&mut f),
        [
            request(1, &ones[..64]),
            request(1, &ones[64..]),
            request(2, &[2, 6, 10])
        ]
    );
    assert_eq!(f.stats().requests, 3);
    assert_eq!(f.in_flight(), 103);
}

#[test]
#[cfg_attr(debug_assertions, should_panic(expected = "never misses"))]
fn a_block_held_here_is_never_requested() {
    // Node 1 of 3 with two replicas holds blocks 1, 4, … and 0, 3, ….
    let mut f = fetcher(12, 3, 1, 2, 64);
    let now = Instant::now();
    f.handle_miss(4, now);
    f.handle_miss(3, now);
    f.flush(now);
    assert_eq!(drain(&mut f), []);
}

#[test]
fn an_unanswered_request_goes_round_the_owners() {
    // Block 1 of 3 nodes, two replicas: owners 1 then 2; this is node 0.
    let mut f = fetcher(12, 3, 0, 2, 64);
    let t0 = Instant::now();
    f.handle_miss(1, t0);
    f.flush(t0);
    assert_eq!(drain(&mut f), [request(1, &[1])]);
    assert_eq!(f.poll_timeout(), Some(t0 + 10 * MS));
    f.handle_timeout(t0 + 9 * MS);
    assert_eq!(drain(&mut f), [], "not yet due");
    f.handle_timeout(t0 + 10 * MS);
    assert_eq!(drain(&mut f), [request(2, &[1])]);
    f.handle_timeout(t0 + 20 * MS);
    assert_eq!(drain(&mut f), [request(1, &[1])], "round robin");
    assert_eq!(f.stats().retries, 2);
    // The answer to the first request counts, wherever it came from; later ones are copies.
    assert_eq!(f.handle_arrived(1, Some(1), t0 + 25 * MS), Some(25 * MS));
    assert_eq!(f.handle_arrived(1, Some(2), t0 + 26 * MS), None);
    assert_eq!(f.poll_timeout(), None);
    assert_eq!(f.stats().duplicates, 1);
}

#[test]
fn a_lone_owner_is_asked_again_after_a_timeout() {
    let mut f = fetcher(8, 2, 0, 1, 64);
    let t0 = Instant::now();
    f.handle_miss(3, t0);
    f.flush(t0);
    f.handle_timeout(t0 + 10 * MS);
    assert_eq!(drain(&mut f), [request(1, &[3]), request(1, &[3])]);
}

#[test]
fn a_lost_peers_requests_move_to_the_next_owner_then_to_the_disk() {
    // Four nodes, two replicas; node 0 wants block 1 (owners 1, 2) and block 2 (owners 2, 3).
    let mut f = fetcher(16, 4, 0, 2, 64);
    let t0 = Instant::now();
    f.handle_miss(1, t0);
    f.handle_miss(2, t0);
    f.flush(t0);
    assert_eq!(drain(&mut f), [request(1, &[1]), request(2, &[2])]);
    f.handle_peer_lost(1, t0 + MS);
    assert_eq!(drain(&mut f), [request(2, &[1])]);
    f.handle_peer_lost(2, t0 + 2 * MS);
    assert_eq!(
        drain(&mut f),
        [FetchOutput::ReadLocally { block: 1 }, request(3, &[2])]
    );
    // A new miss skips the lost primary.
    f.handle_miss(5, t0 + 3 * MS);
    f.flush(t0 + 3 * MS);
    assert_eq!(drain(&mut f), [FetchOutput::ReadLocally { block: 5 }]);
    assert_eq!(f.handle_arrived(1, None, t0 + 4 * MS), Some(4 * MS));
    assert_eq!(f.stats().read_locally, 2);
    assert_eq!(f.stats().retries, 0, "a loss is not a timeout");
    f.handle_peer_back(1);
    f.handle_miss(9, t0 + 5 * MS);
    f.flush(t0 + 5 * MS);
    assert_eq!(drain(&mut f), [request(1, &[9])]);
}

#[test]
fn the_deadline_follows_the_oldest_request_still_unanswered() {
    let mut f = fetcher(16, 4, 0, 1, 64);
    let t0 = Instant::now();
    f.handle_miss(1, t0);
    f.flush(t0);
    f.handle_miss(2, t0 + MS);
    f.flush(t0 + MS);
    assert_eq!(f.poll_timeout(), Some(t0 + 10 * MS));
    f.handle_arrived(1, Some(1), t0 + 2 * MS);
    assert_eq!(f.poll_timeout(), Some(t0 + 11 * MS));
    f.handle_arrived(2, Some(2), t0 + 3 * MS);
    assert_eq!(f.poll_timeout(), None);
    let latency = f.stats().latency;
    assert_eq!(latency.count, 2);
    assert_eq!((latency.min_us, latency.max_us), (2000.0, 2000.0));
}

#[test]
fn latency_summaries_merge_exactly_but_for_p99_which_is_bounded() {
    let a = LatencySummary {
        count: 3,
        min_us: 10.0,
        avg_us: 20.0,
        max_us: 40.0,
        p99_us: 40.0,
    };
    let b = LatencySummary {
        count: 1,
        min_us: 4.0,
        avg_us: 4.0,
        max_us: 4.0,
        p99_us: 4.0,
    };
    let m = a.merge(&b);
    assert_eq!(
        (m.count, m.min_us, m.avg_us, m.max_us),
        (4, 4.0, 16.0, 40.0)
    );
    assert_eq!(m.p99_us, 40.0);
    assert_eq!(a.merge(&LatencySummary::default()), a);
    assert_eq!(LatencySummary::default().merge(&b), b);
    let mut stats = FetchStats {
        misses: 2,
        latency: a,
        ..FetchStats::default()
    };
    stats.merge(&FetchStats {
        misses: 5,
        latency: b,
        ..FetchStats::default()
    });
    assert_eq!((stats.misses, stats.latency.count), (7, 4));
}

#[derive(Clone, Debug)]
enum Op {
    Miss(BlockId),
    Flush,
    Arrive(BlockId),
    Lose(u32),
    Back(u32),
    Tick(u64),
}

fn ops(total: u32, ranks: u32) -> impl Strategy<Value = Vec<Op>> {
    let op = prop_oneof![
        4 => (0..total).prop_map(Op::Miss),
        2 => Just(Op::Flush),
        2 => (0..total).prop_map(Op::Arrive),
        1 => (0..ranks).prop_map(Op::Lose),
        1 => (0..ranks).prop_map(Op::Back),
        2 => (0u64..30).prop_map(Op::Tick),
    ];
    proptest::collection::vec(op, 0..80)
}

proptest! {
    #[test]
    fn requests_go_only_to_live_owners_other_than_this_node_and_fit_the_batch(
        ops in ops(40, 5), replicas in 1u32..=3, batch_max in 1usize..4
    ) {
        let mut f = fetcher(40, 5, 0, replicas, batch_max);
        let residency = f.residency().clone();
        let t0 = Instant::now();
        let mut now = t0;
        let mut lost = BTreeSet::new();
        for op in ops {
            match op {
                Op::Miss(k) if !residency.owns(k) => f.handle_miss(k, now),
                Op::Miss(_) => {}
                Op::Flush => f.flush(now),
                Op::Arrive(k) => {
                    f.handle_arrived(k, None, now);
                }
                Op::Lose(r) => {
                    lost.insert(r);
                    f.handle_peer_lost(r, now);
                }
                Op::Back(r) => {
                    lost.remove(&r);
                    f.handle_peer_back(r);
                }
                Op::Tick(ms) => {
                    now += Duration::from_millis(ms);
                    f.handle_timeout(now);
                }
            }
            while let Some(out) = f.poll_output() {
                if let FetchOutput::Request { peer, blocks, .. } = out {
                    prop_assert!(peer != 0 && !lost.contains(&peer));
                    prop_assert!(!blocks.is_empty() && blocks.len() <= batch_max);
                    for k in blocks {
                        prop_assert!(residency.owners(k).any(|o| o == peer));
                    }
                }
            }
            prop_assert!(f.poll_timeout().is_none_or(|at| at > now));
        }
    }
}

#[test]
fn a_prefetched_block_a_thread_then_misses_is_asked_again_as_a_miss() {
    let mut f = fetcher(16, 4, 0, 1, 64);
    let now = Instant::now();
    f.handle_prefetch(5, now);
    f.handle_prefetch(9, now);
    f.handle_miss(6, now);
    f.flush(now);
    // Misses go out first, each request all misses or all prefetches.
    assert_eq!(
        drain(&mut f),
        vec![
            request(2, &[6]),
            FetchOutput::Request {
                peer: 1,
                blocks: vec![5, 9],
                ahead: true
            },
        ]
    );
    f.handle_miss(5, now);
    f.flush(now);
    assert_eq!(drain(&mut f), vec![request(1, &[5])]);
    assert_eq!(f.stats().promoted, 1);
    // The first copy counts; the prefetch's own answer is a duplicate.
    assert!(f.handle_arrived(5, Some(1), now).is_some());
    assert!(f.handle_arrived(5, Some(1), now).is_none());
    // A miss of a block already asked as a miss is not asked again.
    f.handle_miss(6, now);
    f.flush(now);
    assert!(drain(&mut f).is_empty());
}
