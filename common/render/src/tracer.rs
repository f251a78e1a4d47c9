//! A render thread's means of tracing rays through a prepared scene's triangles, whichever
//! memory holds them: the scene's own arrays (replicated data) or the distributed shared
//! memory, where the thread keeps the blocks it is in (see `dsm::DsmReader`).

use crate::bvh::memory::TreeMemory;
use crate::bvh::node::{Hit, LeafTriangle};
use crate::dsm::DsmReader;
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
}

// One per render thread, made once: boxing the large variant would only add a pointer chase to
// every node a traversal reads.
#[allow(clippy::large_enum_variant)]
enum Memory<'s> {
    Resident(crate::bvh::memory::Resident<'s>),
    Dsm(DsmReader<'s>),
}

impl<'s> Tracer<'s> {
    pub(crate) fn new(scene: &'s PreparedScene) -> Self {
        let memory = match &scene.shared {
            Some(tree) => Memory::Dsm(tree.reader()),
            None => Memory::Resident(scene.accel.resident()),
        };
        Tracer {
            stack: scene.accel.new_stack(),
            memory,
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
            Memory::Dsm(m) => closest_hit(m, ray, (t_min, t_max), stack),
        }
    }

    /// Whether a triangle blocks the ray in `(t_min, t_max)`.
    pub fn occluded(&mut self, ray: &Ray, t_min: f32, t_max: f32) -> bool {
        use crate::bvh::traverse_ray::occluded;
        let stack = &mut self.stack;
        match &mut self.memory {
            Memory::Resident(m) => occluded(m, ray, (t_min, t_max), stack),
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

    /// Leaf triangle `slot` (a hit's), for shading.
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
