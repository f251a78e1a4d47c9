//! A render thread's means of tracing rays through a prepared scene's triangles, whichever
//! memory holds them: the scene's own arrays (replicated data) or the distributed shared
//! memory, where the thread keeps the blocks it is in (see `dsm::DsmReader`).

use crate::bvh::memory::TreeMemory;
use crate::bvh::node::BvhNode;
use crate::bvh::node::{Hit, LeafTriangle};
use crate::dsm::{DsmReader, Landing, Pins};
use crate::scene::particles::Particle;
use crate::spheres::{Replicated, SphereAccel, SphereSource};
use crate::volume::{BrickSource, Bricks};
use tessera_core::dsm::BlockId;

/// What a packet's earlier traces leave to its next one (see `parking`): the blocks they read
/// or missed, and the single rays' answers they got whole, so that the next trace does not
/// trace those rays again (an ambient-occlusion packet sends hundreds of them).
#[derive(Default)]
pub struct Carried {
    /// See [`Pins`].
    pub pins: Pins,
    answers: Answers,
}

impl Carried {
    /// Bytes of blocks it keeps alive.
    pub fn pinned_bytes(&self) -> usize {
        self.pins.iter().map(|(_, b)| b.bytes().len()).sum()
    }
}

/// A single ray's query: which (closest hit or occlusion), its origin, direction and interval,
/// as bits: a query of the same bits has the same answer, the scene being the same.
type Query = [u32; 9];

/// The kinds of [`Query`].
const CLOSEST: u32 = 0;
const OCCLUDED: u32 = 1;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Answer {
    Occluded(bool),
    Closest(Option<Hit>),
}

/// Single-ray answers got without a miss: this trace's, in order, and its earlier traces',
/// sorted by query.
#[derive(Default)]
struct Answers {
    new: Vec<(Query, Answer)>,
    known: Vec<(Query, Answer)>,
}

impl Answers {
    fn query(kind: u32, ray: &Ray, t_min: f32, t_max: f32) -> Query {
        let (o, d) = (ray.origin, ray.dir);
        let words = [o.x, o.y, o.z, d.x, d.y, d.z, t_min, t_max].map(f32::to_bits);
        let mut query = [kind; 9];
        query[1..].copy_from_slice(&words);
        query
    }

    fn known(&self, query: &Query) -> Option<Answer> {
        let at = self.known.binary_search_by(|(q, _)| q.cmp(query)).ok()?;
        Some(self.known[at].1)
    }

    /// The answer to `query`: an earlier trace's, or `trace`'s now, kept if this trace has
    /// missed nothing so far.
    fn answer(
        &mut self,
        query: Query,
        reader: &mut DsmReader<'_>,
        trace: impl FnOnce(&mut DsmReader<'_>) -> Answer,
    ) -> Answer {
        if let Some(known) = self.known(&query) {
            return known;
        }
        let answer = trace(reader);
        if reader.missed_count() == 0 {
            self.new.push((query, answer));
        }
        answer
    }

    /// This trace's answers join the known ones (the trace missed a block and will be
    /// traced again).
    fn keep(&mut self) {
        self.known.append(&mut self.new);
        self.known.sort_unstable_by_key(|a| a.0);
        self.known.dedup_by(|a, b| a.0 == b.0);
    }
}
use crate::geometry::Ray;
use crate::isa::Isa;
use crate::packet::{PacketHit, RayPacket, PACKET_RAYS};
use crate::PreparedScene;

/// One thread's traversal state: a stack, and for a scene in shared memory the blocks it holds.
/// Make one per thread with [`PreparedScene::tracer`] and reuse it across rays.
pub struct Tracer<'s> {
    /// Also the stack of the particles' binary tree.
    pub stack: Vec<u32>,
    memory: Memory<'s>,
    /// For a trace that may be traced again (see [`Carried`]).
    answers: Answers,
    /// Whether single rays' answers are looked up and kept. Only answers got before the
    /// trace's first miss are kept: after it, a ray may read a stand-in from the reader's
    /// table without a new miss.
    answering: bool,
}

// One per render thread, made once: boxing the large variant would only add a pointer chase to
// every node a traversal reads.
#[allow(clippy::large_enum_variant)]
enum Memory<'s> {
    Resident(crate::bvh::memory::Resident<'s>),
    Dsm(DsmReader<'s>),
}

impl BrickSource for Tracer<'_> {
    #[inline]
    fn samples<'a>(&'a mut self, bricks: &'a Bricks, index: usize) -> Option<&'a [f32]> {
        match &mut self.memory {
            Memory::Dsm(reader) if bricks.is_shared() => reader.samples(bricks, index),
            _ => Some(bricks.local_samples(index)),
        }
    }
}

/// A tracer's memory read as particles: the structure's own arrays, or shared ones through the
/// thread's reader.
struct SphereReads<'a, 's>(&'a mut Memory<'s>);

impl SphereSource for SphereReads<'_, '_> {
    #[inline]
    fn sphere_node(&mut self, accel: &SphereAccel, index: u32) -> Option<BvhNode> {
        match self.0 {
            Memory::Dsm(reader) if accel.is_shared() => reader.sphere_node(index),
            _ => Replicated.sphere_node(accel, index),
        }
    }

    #[inline]
    fn sphere(&mut self, accel: &SphereAccel, slot: u32) -> Option<Particle> {
        match self.0 {
            Memory::Dsm(reader) if accel.is_shared() => reader.sphere(slot),
            _ => Replicated.sphere(accel, slot),
        }
    }
}

impl<'s> Tracer<'s> {
    /// The nearest particle hit in `(t_min, t_max)` among those whose attribute is in `crop`
    /// (see [`SphereAccel::closest_hit`]).
    pub fn sphere_hit(
        &mut self,
        spheres: &SphereAccel,
        (ray, t_min, t_max): (&Ray, f32, f32),
        crop: Option<(f32, f32)>,
    ) -> Option<(f32, u32, Particle)> {
        let Tracer { stack, memory, .. } = self;
        spheres.closest_hit(&mut SphereReads(memory), (ray, t_min, t_max), crop, stack)
    }

    /// Whether a particle whose attribute is in `crop` blocks the ray in `(t_min, t_max)`.
    pub fn sphere_occluded(
        &mut self,
        spheres: &SphereAccel,
        (ray, t_min, t_max): (&Ray, f32, f32),
        crop: Option<(f32, f32)>,
    ) -> bool {
        let Tracer { stack, memory, .. } = self;
        spheres.occluded(&mut SphereReads(memory), (ray, t_min, t_max), crop, stack)
    }

    pub(crate) fn new(scene: &'s PreparedScene) -> Self {
        let memory = match &scene.shared {
            Some(tree) => Memory::Dsm(tree.reader()),
            None => Memory::Resident(scene.accel.resident()),
        };
        Tracer {
            stack: scene.accel.new_stack(),
            memory,
            answers: Answers::default(),
            answering: false,
        }
    }

    /// Closest triangle hits of a packet (see `bvh::traverse_packet`).
    pub fn closest_hits(&mut self, packet: &mut RayPacket, hits: &mut [PacketHit; PACKET_RAYS]) {
        use crate::bvh::traverse_packet::closest_hits_on;
        let (stack, isa) = (&mut self.stack, Isa::best());
        match &mut self.memory {
            Memory::Resident(m) => closest_hits_on(isa, m, packet, hits, stack),
            Memory::Dsm(m) => closest_hits_on(isa, m, packet, hits, stack),
        }
    }

    /// Which rays of a packet are blocked, as bits (see `bvh::traverse_packet`).
    pub fn occluded_lanes(&mut self, packet: &mut RayPacket) -> u64 {
        use crate::bvh::traverse_packet::occluded_lanes_on;
        let (stack, isa) = (&mut self.stack, Isa::best());
        match &mut self.memory {
            Memory::Resident(m) => occluded_lanes_on(isa, m, packet, stack),
            Memory::Dsm(m) => occluded_lanes_on(isa, m, packet, stack),
        }
    }

    /// The nearest triangle hit in `(t_min, t_max)`.
    pub fn closest_hit(&mut self, ray: &Ray, t_min: f32, t_max: f32) -> Option<Hit> {
        use crate::bvh::traverse_ray::closest_hit;
        let stack = &mut self.stack;
        match &mut self.memory {
            Memory::Resident(m) => closest_hit(m, ray, (t_min, t_max), stack),
            Memory::Dsm(m) if self.answering => {
                let query = Answers::query(CLOSEST, ray, t_min, t_max);
                let trace = |m: &mut DsmReader<'_>| {
                    Answer::Closest(closest_hit(m, ray, (t_min, t_max), stack))
                };
                match self.answers.answer(query, m, trace) {
                    Answer::Closest(hit) => hit,
                    Answer::Occluded(_) => unreachable!("a closest-hit query has its own kind"),
                }
            }
            Memory::Dsm(m) => closest_hit(m, ray, (t_min, t_max), stack),
        }
    }

    /// Whether a triangle blocks the ray in `(t_min, t_max)`.
    pub fn occluded(&mut self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        use crate::bvh::traverse_ray::occluded;
        let stack = &mut self.stack;
        match &mut self.memory {
            Memory::Resident(m) => occluded(m, ray, (t_min, t_max), stack),
            Memory::Dsm(m) if self.answering => {
                let query = Answers::query(OCCLUDED, ray, t_min, t_max);
                let trace = |m: &mut DsmReader<'_>| {
                    Answer::Occluded(occluded(m, ray, (t_min, t_max), stack))
                };
                match self.answers.answer(query, m, trace) {
                    Answer::Occluded(blocked) => blocked,
                    Answer::Closest(_) => unreachable!("an occlusion query has its own kind"),
                }
            }
            Memory::Dsm(m) => occluded(m, ray, (t_min, t_max), stack),
        }
    }

    /// The other nodes' blocks this tracer read since the last call (none for replicated
    /// data), in the order read.
    pub fn take_footprint(&mut self) -> Vec<tessera_core::dsm::BlockId> {
        match &mut self.memory {
            Memory::Resident(_) => Vec::new(),
            Memory::Dsm(m) => m.take_footprint(),
        }
    }

    /// For a scene in shared memory: whether a missing block is parked rather than waited
    /// for, and blocks to read as if held (see `dsm::DsmReader::park_misses`). Replicated
    /// data never misses.
    pub fn park_misses(&mut self, on: bool, carried: Carried) {
        if let Memory::Dsm(m) = &mut self.memory {
            m.park_misses(on, carried.pins);
            self.answering = on || !carried.answers.known.is_empty();
            self.answers = carried.answers;
            self.answers.new.clear();
        }
    }

    /// The blocks missed since the last call and the pins handed in (see
    /// `dsm::DsmReader::take_missed`): if any was missed, what was traced since is void.
    pub fn take_missed(&mut self) -> (Vec<(BlockId, Landing)>, Carried) {
        let Memory::Dsm(m) = &mut self.memory else {
            return (Vec::new(), Carried::default());
        };
        let (missed, pins) = m.take_missed();
        let mut answers = std::mem::take(&mut self.answers);
        if missed.is_empty() {
            answers = Answers::default();
        } else {
            answers.keep();
        }
        self.answering = false;
        (missed, Carried { pins, answers })
    }

    /// Whether a block was missed since [`Tracer::take_missed`] (see
    /// `dsm::DsmReader::missed_count`).
    pub fn has_missed(&self) -> bool {
        match &self.memory {
            Memory::Resident(_) => false,
            Memory::Dsm(m) => m.missed_count() > 0,
        }
    }

    /// Leaf triangle `slot` (a hit's), for shading.
    #[inline]
    pub fn triangle(&mut self, slot: u32) -> LeafTriangle {
        match &mut self.memory {
            Memory::Resident(m) => *m.triangle(slot),
            Memory::Dsm(m) => *m.triangle(slot),
        }
    }
}

impl PreparedScene {
    /// A tracer for one thread (see [`Tracer`]).
    pub fn tracer(&self) -> Tracer<'_> {
        Tracer::new(self)
    }
}
