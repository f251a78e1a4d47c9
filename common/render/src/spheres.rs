//! Spheres (particles): their own BVH, built only when a scene has any, a numerically careful
//! ray–sphere test, and the colour map and crop range that their scalar attribute drives.
//!
//! The tree and the spheres are read through a [`SphereSource`]: the structure's own arrays
//! ([`Replicated`]), or for particles in distributed shared memory a render thread's reader,
//! which answers `None` for a block that has not landed; the walk then passes over it and the
//! caller traces the same rays again once it has (see `crate::parking`).

use crate::bvh::node::BvhNode;
use crate::geometry::Ray;
use crate::scene::particles::Particle;
use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::BvhBuildParams;
use std::time::Duration;

/// Spheres in leaf order with a binary BVH over them.
pub struct SphereAccel {
    nodes: Vec<BvhNode>,
    /// The particles in leaf order (render coordinates): leaf slots index this. Empty for
    /// particles in shared memory.
    pub spheres: Vec<Particle>,
    /// Scene particle index of each leaf slot (empty for particles in shared memory: only AOVs
    /// read it).
    pub scene_index: Vec<u32>,
    /// Particles in all, wherever they are held.
    count: u32,
    /// Whether the tree and the particles are in distributed shared memory, not here.
    shared: bool,
}

/// Where a walk reads a [`SphereAccel`]'s tree nodes and spheres.
pub trait SphereSource {
    /// Node `index` of the tree, or `None` if it is not here yet.
    fn sphere_node(&mut self, accel: &SphereAccel, index: u32) -> Option<BvhNode>;
    /// The sphere in leaf slot `slot`, or `None` if it is not here yet.
    fn sphere(&mut self, accel: &SphereAccel, slot: u32) -> Option<Particle>;
}

/// The structure's own arrays.
pub struct Replicated;

impl SphereSource for Replicated {
    #[inline]
    fn sphere_node(&mut self, accel: &SphereAccel, index: u32) -> Option<BvhNode> {
        accel.nodes.get(index as usize).copied()
    }

    #[inline]
    fn sphere(&mut self, accel: &SphereAccel, slot: u32) -> Option<Particle> {
        accel.spheres.get(slot as usize).copied()
    }
}

impl SphereAccel {
    /// `None` for a scene without particles: no structure is built that nothing would use.
    pub fn build(particles: &[Particle]) -> Option<SphereAccel> {
        if particles.is_empty() {
            return None;
        }
        let boxes: Vec<Aabb> = particles
            .iter()
            .map(|p| {
                Aabb::new(
                    Vec3A::from(p.center - Vec3::splat(p.radius)),
                    Vec3A::from(p.center + Vec3::splat(p.radius)),
                )
            })
            .collect();
        let bvh = build_bvh2(
            &boxes,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        Some(SphereAccel {
            count: particles.len() as u32,
            shared: false,
            nodes: bvh.nodes.iter().map(BvhNode::from).collect(),
            spheres: bvh
                .primitive_indices
                .iter()
                .map(|&i| particles[i as usize])
                .collect(),
            scene_index: bvh.primitive_indices,
        })
    }

    /// Particles in shared memory, `count` of them: the tree and the particles are read
    /// through a render thread's reader.
    pub fn shared(count: u32) -> SphereAccel {
        SphereAccel {
            nodes: Vec::new(),
            spheres: Vec::new(),
            scene_index: Vec::new(),
            count,
            shared: true,
        }
    }

    /// Whether the tree and the particles are in distributed shared memory.
    pub fn is_shared(&self) -> bool {
        self.shared
    }

    /// Particles in all.
    pub fn len(&self) -> usize {
        self.count as usize
    }

    /// Never: a structure is built only for a scene with particles.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The tree's nodes.
    pub fn nodes(&self) -> &[BvhNode] {
        &self.nodes
    }

    /// The tree's nodes and the particles in leaf order (for writing them as blocks).
    pub fn into_parts(self) -> (Vec<BvhNode>, Vec<Particle>) {
        (self.nodes, self.spheres)
    }

    /// The nearest sphere hit in `(t_min, t_max)` among spheres whose attribute is in `crop`:
    /// its distance, leaf slot and sphere.
    pub fn closest_hit(
        &self,
        src: &mut impl SphereSource,
        (ray, t_min, t_max): (&Ray, f32, f32),
        crop: Option<(f32, f32)>,
        stack: &mut Vec<u32>,
    ) -> Option<(f32, u32, Particle)> {
        let mut best = None;
        let mut far = t_max;
        self.walk(src, ray, stack, &mut far, |src, slot, far| {
            let Some(s) = src.sphere(self, slot) else {
                return false;
            };
            if let Some(t) = hit_sphere(ray, &s, t_min, *far).filter(|_| in_crop(&s, crop)) {
                *far = t;
                best = Some((t, slot, s));
            }
            false
        });
        best
    }

    /// Whether any sphere whose attribute is in `crop` is hit in `(t_min, t_max)`: a shadow ray's
    /// test, which stops at the first.
    pub fn occluded(
        &self,
        src: &mut impl SphereSource,
        (ray, t_min, t_max): (&Ray, f32, f32),
        crop: Option<(f32, f32)>,
        stack: &mut Vec<u32>,
    ) -> bool {
        let mut far = t_max;
        let mut blocked = false;
        self.walk(src, ray, stack, &mut far, |src, slot, far| {
            blocked = src
                .sphere(self, slot)
                .is_some_and(|s| in_crop(&s, crop) && hit_sphere(ray, &s, t_min, *far).is_some());
            blocked
        });
        blocked
    }

    /// Visits the leaf slots whose boxes the ray enters before `t_far`, nearer child first; a
    /// node `src` does not have is passed over. `visit` may shrink `t_far` and returns `true`
    /// to stop.
    #[inline(always)]
    fn walk<S: SphereSource>(
        &self,
        src: &mut S,
        ray: &Ray,
        stack: &mut Vec<u32>,
        t_far: &mut f32,
        mut visit: impl FnMut(&mut S, u32, &mut f32) -> bool,
    ) {
        stack.clear();
        let Some(root) = src.sphere_node(self, 0) else {
            return;
        };
        if ray.box_entry(root.min, root.max, *t_far).is_infinite() {
            return;
        }
        stack.push(0);
        while let Some(index) = stack.pop() {
            // A node that is not here holds nothing: the trace is void anyway.
            let Some(node) = src.sphere_node(self, index) else {
                continue;
            };
            if node.count > 0 {
                for slot in node.first..node.first + node.count {
                    if visit(src, slot, t_far) {
                        return;
                    }
                }
                continue;
            }
            let (l, r) = (node.first, node.first + 1);
            let entry = |n: Option<BvhNode>| {
                n.map_or(f32::INFINITY, |n| ray.box_entry(n.min, n.max, *t_far))
            };
            let tl = entry(src.sphere_node(self, l));
            let tr = entry(src.sphere_node(self, r));
            // Push the farther child first so the nearer one is popped next.
            match (tl.is_finite(), tr.is_finite()) {
                (true, true) if tl <= tr => stack.extend([r, l]),
                (true, true) => stack.extend([l, r]),
                (true, false) => stack.push(l),
                (false, true) => stack.push(r),
                (false, false) => {}
            }
        }
    }
}

fn in_crop(s: &Particle, crop: Option<(f32, f32)>) -> bool {
    crop.is_none_or(|(lo, hi)| s.attribute >= lo && s.attribute <= hi)
}

/// Ray–sphere distance (in units of `ray.dir`). The discriminant is computed from the distance
/// of the centre to the ray's line rather than as b² − c, which cancels catastrophically for
/// small spheres far away (Haines et al., Ray Tracing Gems ch. 7).
pub fn hit_sphere(ray: &Ray, s: &Particle, t_min: f32, t_max: f32) -> Option<f32> {
    let len2 = ray.dir.length_squared();
    let oc = ray.origin - s.center;
    let b = oc.dot(ray.dir) / len2;
    let closest = oc - ray.dir * b;
    let h = s.radius * s.radius - closest.length_squared();
    if h < 0.0 {
        return None;
    }
    let root = (h / len2).sqrt();
    [-b - root, -b + root]
        .into_iter()
        .find(|&t| t > t_min && t < t_max)
}

/// Colour of an attribute value normalized to [0, 1]: a perceptually ordered ramp from deep
/// blue through teal and yellow-green to yellow (close to viridis).
pub fn colormap(x: f32) -> Vec3 {
    Vec3::from_array(tessera_model::colormap::ColorMap::Viridis.eval(x))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f32, attribute: f32) -> Particle {
        Particle {
            center: Vec3::new(x, 0.0, 0.0),
            radius: 0.5,
            attribute,
        }
    }

    #[test]
    fn nearest_sphere_wins_and_crop_hides_spheres() {
        let accel = SphereAccel::build(&[p(0.0, 1.0), p(3.0, 5.0), p(-3.0, 9.0)]).unwrap();
        let mut stack = Vec::new();
        let ray = Ray::new(Vec3::new(10.0, 0.0, 0.0), Vec3::NEG_X);
        let src = &mut Replicated;
        let (t, slot, _) = accel
            .closest_hit(src, (&ray, 0.0, f32::INFINITY), None, &mut stack)
            .unwrap();
        assert!((t - 6.5).abs() < 1e-5);
        assert_eq!(accel.scene_index[slot as usize], 1);
        let (t, _, s) = accel
            .closest_hit(
                src,
                (&ray, 0.0, f32::INFINITY),
                Some((0.0, 2.0)),
                &mut stack,
            )
            .unwrap();
        assert_eq!(s.attribute, 1.0);
        assert!(
            (t - 9.5).abs() < 1e-5,
            "the sphere with attribute 5 is cropped away"
        );
        let far = (&ray, 0.0, f32::INFINITY);
        assert!(!accel.occluded(src, far, Some((100.0, 200.0)), &mut stack));
        assert!(accel.occluded(src, far, None, &mut stack));
    }

    #[test]
    fn no_particles_no_structure() {
        assert!(SphereAccel::build(&[]).is_none());
    }

    #[test]
    fn tiny_far_spheres_are_still_hit_from_inside_and_out() {
        let s = Particle {
            center: Vec3::new(0.0, 0.0, -1e4),
            radius: 1e-3,
            attribute: 0.0,
        };
        let ray = Ray::new(Vec3::new(0.0, 0.0, 0.0), Vec3::NEG_Z);
        let t = hit_sphere(&ray, &s, 0.0, f32::INFINITY).expect("hit");
        assert!((t - (1e4 - 1e-3)).abs() < 2e-3, "{t}");
        let inside = Ray::new(s.center, Vec3::X);
        assert!((hit_sphere(&inside, &s, 0.0, f32::INFINITY).unwrap() - 1e-3).abs() < 1e-6);
    }

    #[test]
    fn colormap_is_finite_and_ordered_by_brightness() {
        let lum = |c: Vec3| c.dot(Vec3::new(0.2126, 0.7152, 0.0722));
        assert!(lum(colormap(0.0)) < lum(colormap(0.5)) && lum(colormap(0.5)) < lum(colormap(1.0)));
        assert!(colormap(f32::NAN).is_finite() && colormap(7.0) == colormap(1.0));
    }
}
