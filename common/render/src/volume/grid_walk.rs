//! Walking a ray through a regular grid cell by cell (Amanatides and Woo's 3-D DDA), in the
//! volume's index space: used with cells of one voxel for iso-surfaces and of a macro-cell for
//! empty-space skipping.
//!
//! Consecutive segments share their boundary value exactly, so a sample position `k · step`
//! belongs to one segment only, whatever the grid: skipping cells changes which samples are
//! taken, never where.

/// A ray `origin + t · dir` in index space (the grid's cell `c` along axis `a` spans
/// `c · size .. (c + 1) · size`).
#[derive(Clone, Copy, Debug)]
pub struct IndexRay {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
}

/// One cell of the walk and the part of the ray inside it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    pub cell: [usize; 3],
    pub t0: f32,
    pub t1: f32,
}

/// The cells a ray crosses between `t_start` and `t_end`, in order.
pub struct GridWalk {
    cell: [i64; 3],
    step: [i64; 3],
    next: [f32; 3],
    origin: [f32; 3],
    dir: [f32; 3],
    /// 1 / direction (infinite along an axis the ray does not move on, never used there): a
    /// multiply a segment instead of a divide.
    inv_dir: [f32; 3],
    size: f32,
    counts: [i64; 3],
    t: f32,
    t_end: f32,
}

impl GridWalk {
    /// Starts at `t_start`, where the ray must be inside (or on the surface of) the grid of
    /// `counts` cells of edge `size`.
    pub fn new(ray: &IndexRay, size: f32, counts: [usize; 3], t_start: f32, t_end: f32) -> Self {
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        let mut next = [f32::INFINITY; 3];
        // The cell holding the ray a little after the start: on a boundary, the one it enters.
        let t_probe = t_start + (t_end - t_start).min(size) * 1e-4;
        for a in 0..3 {
            let p = ray.origin[a] + ray.dir[a] * t_probe;
            // The ray is inside the grid here, so truncation is floor (and `floor` is a libm
            // call on baseline x86-64, once per axis per ray).
            cell[a] = ((p / size).max(0.0) as i64).min(counts[a] as i64 - 1);
            let d = ray.dir[a];
            if d > 0.0 {
                step[a] = 1;
                next[a] = ((cell[a] + 1) as f32 * size - ray.origin[a]) * (1.0 / d);
            } else if d < 0.0 {
                step[a] = -1;
                next[a] = (cell[a] as f32 * size - ray.origin[a]) * (1.0 / d);
            }
        }
        GridWalk {
            cell,
            step,
            next,
            origin: ray.origin,
            dir: ray.dir,
            inv_dir: ray.dir.map(|d| 1.0 / d),
            size,
            counts: counts.map(|c| c as i64),
            t: t_start,
            t_end,
        }
    }
}

impl GridWalk {
    /// Leaves the cube of cells within `radius` (L∞) of `centre` at once, when the caller knows
    /// it holds nothing to see: the walk goes on from where the ray crosses the cube's far face,
    /// in the cell beyond it. The crossing is computed as the walk computes every boundary, so
    /// the segments after a leap start where they would have without it.
    pub fn leap_out_of(&mut self, centre: [usize; 3], radius: usize) {
        let mut exit = self.t_end;
        let mut exit_axis = None;
        let mut beyond = [0i64; 3];
        for a in 0..3 {
            let step = self.step[a];
            if step == 0 {
                continue;
            }
            let c = centre[a] as i64;
            let last = if step > 0 {
                (c + radius as i64).min(self.counts[a] - 1)
            } else {
                (c - radius as i64).max(0)
            };
            beyond[a] = last + step;
            let t = self.boundary_t(a, last + (step > 0) as i64);
            if t < exit {
                (exit, exit_axis) = (t, Some(a));
            }
        }
        let Some(axis) = exit_axis else {
            // The cube reaches past the end of the ray: nothing is left to walk.
            self.t = self.t_end;
            return;
        };
        if exit <= self.t {
            return;
        }
        self.t = exit;
        for a in 0..3 {
            self.cell[a] = if a == axis {
                beyond[a]
            } else {
                // Inside the cube on this axis at the crossing: the cell from the position,
                // kept within the cube (and the grid) against rounding.
                let p = self.origin[a] + self.dir[a] * exit;
                let c = centre[a] as i64;
                ((p / self.size).max(0.0) as i64)
                    .clamp(c - radius as i64, c + radius as i64)
                    .clamp(0, self.counts[a] - 1)
            };
            if self.step[a] != 0 {
                let boundary = self.cell[a] + (self.step[a] > 0) as i64;
                self.next[a] = self.boundary_t(a, boundary);
            }
        }
    }

    /// Where the ray crosses the plane `boundary · size` of `axis`.
    #[inline]
    fn boundary_t(&self, axis: usize, boundary: i64) -> f32 {
        (boundary as f32 * self.size - self.origin[axis]) * self.inv_dir[axis]
    }
}

impl Iterator for GridWalk {
    type Item = Segment;

    fn next(&mut self) -> Option<Segment> {
        // One unsigned compare per axis covers both ends; `|` rather than `||` keeps it one
        // branch.
        let outside = (0..3).fold(false, |out, a| {
            out | (self.cell[a] as u64 >= self.counts[a] as u64)
        });
        if self.t >= self.t_end || outside {
            return None;
        }
        // The axis of the nearest boundary, chosen without branches: which one it is changes
        // from step to step without a pattern, and a mispredicted branch cost more than the
        // rest of the step.
        let [n0, n1, n2] = self.next;
        let not_x = !((n0 <= n1) & (n0 <= n2));
        let axis = not_x as usize * (1 + (n2 < n1) as usize);
        // Comparisons rather than `f32::min`/`max`, whose NaN handling doubled the work (no
        // value here is NaN).
        let boundary_t = self.next[axis];
        let t1 = if boundary_t < self.t_end {
            boundary_t
        } else {
            self.t_end
        };
        let t1 = if t1 > self.t { t1 } else { self.t };
        let segment = Segment {
            cell: self.cell.map(|c| c as usize),
            t0: self.t,
            t1,
        };
        self.t = t1;
        self.cell[axis] += self.step[axis];
        // Accumulating deltas drifts; computing each boundary from its cell keeps it one value
        // whichever walk reaches it.
        let boundary = self.cell[axis] + (self.step[axis] > 0) as i64;
        self.next[axis] = self.boundary_t(axis, boundary);
        Some(segment)
    }
}

/// Where the ray is inside the box `0..extent` (each axis), clipped to `t_min..t_max`; None if
/// nowhere. Axes the ray runs parallel to keep it if its origin lies within them (a ray along
/// a face is inside).
pub fn clip_to_box(ray: &IndexRay, extent: [f32; 3], t_min: f32, t_max: f32) -> Option<(f32, f32)> {
    let (mut t0, mut t1) = (t_min, t_max);
    for a in 0..3 {
        let (o, d) = (ray.origin[a], ray.dir[a]);
        if d == 0.0 {
            if o < 0.0 || o > extent[a] {
                return None;
            }
            continue;
        }
        let (mut near, mut far) = ((0.0 - o) / d, (extent[a] - o) / d);
        if near > far {
            std::mem::swap(&mut near, &mut far);
        }
        t0 = t0.max(near);
        t1 = t1.min(far);
    }
    (t0 <= t1 && t0.is_finite() && t1.is_finite()).then_some((t0, t1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_diagonal_ray_visits_each_cell_it_crosses_once_and_in_order() {
        let ray = IndexRay {
            origin: [0.0, 0.0, 0.0],
            dir: [0.6, 0.8, 0.0],
        };
        let (t0, t1) = clip_to_box(&ray, [4.0, 4.0, 1.0], 0.0, 100.0).unwrap();
        let segments: Vec<Segment> = GridWalk::new(&ray, 1.0, [4, 4, 1], t0, t1).collect();
        assert_eq!(segments.first().unwrap().cell, [0, 0, 0]);
        assert_eq!(segments.last().unwrap().cell, [2, 3, 0]);
        for pair in segments.windows(2) {
            assert_eq!(pair[0].t1, pair[1].t0);
            let moved: usize = (0..3)
                .map(|a| pair[0].cell[a].abs_diff(pair[1].cell[a]))
                .sum();
            assert_eq!(moved, 1);
        }
        assert_eq!(segments.last().unwrap().t1, t1);
    }

    #[test]
    fn a_ray_along_a_face_stays_inside_and_ends() {
        let ray = IndexRay {
            origin: [-1.0, 2.0, 0.0],
            dir: [1.0, 0.0, 0.0],
        };
        let (t0, t1) = clip_to_box(&ray, [4.0, 4.0, 4.0], 0.0, 100.0).unwrap();
        assert_eq!((t0, t1), (1.0, 5.0));
        let cells: Vec<[usize; 3]> = GridWalk::new(&ray, 1.0, [4, 4, 4], t0, t1)
            .map(|s| s.cell)
            .collect();
        assert_eq!(cells.len(), 4);
        assert!(cells.iter().all(|c| c[1] == 2 && c[2] == 0));
        let miss = IndexRay {
            origin: [-1.0, 4.5, 0.0],
            dir: [1.0, 0.0, 0.0],
        };
        assert_eq!(clip_to_box(&miss, [4.0; 3], 0.0, 100.0), None);
    }

    #[test]
    fn a_leap_lands_where_the_step_by_step_walk_leaves_the_cube() {
        let counts = [13, 9, 11];
        let extent = counts.map(|c| c as f32 * 2.0);
        let nonzero = |walk: GridWalk| -> Vec<Segment> { walk.filter(|s| s.t1 > s.t0).collect() };
        let mut leaps = 0;
        for k in 0..300u32 {
            // Rays from a fixed scatter of origins outside the grid towards points inside it.
            let h = |i: u32| ((k * 7 + i).wrapping_mul(2654435761) % 1000) as f32 / 1000.0;
            let target = [h(1) * extent[0], h(2) * extent[1], h(3) * extent[2]];
            let origin = [-5.0 + 3.0 * h(4), 30.0 * h(5) - 5.0, 40.0 * h(6) - 8.0];
            let dir = std::array::from_fn(|a| target[a] - origin[a]);
            let ray = IndexRay { origin, dir };
            let Some((t0, t1)) = clip_to_box(&ray, extent, 0.0, 100.0) else {
                continue;
            };
            let plain = nonzero(GridWalk::new(&ray, 2.0, counts, t0, t1));
            let Some(centre) = plain.get(1 + k as usize % 3).map(|s| s.cell) else {
                continue;
            };
            let radius = 1 + k as usize % 4;
            let mut leaping = GridWalk::new(&ray, 2.0, counts, t0, t1);
            while let Some(s) = leaping.next() {
                if s.cell == centre {
                    leaping.leap_out_of(centre, radius);
                    break;
                }
            }
            let after_leap = nonzero(leaping);
            let in_cube = |c: [usize; 3]| (0..3).all(|a| c[a].abs_diff(centre[a]) <= radius);
            // A ray leaves a cube once: what follows the leap is what follows the first
            // segment outside the cube after the centre.
            let at = plain.iter().position(|s| s.cell == centre).unwrap();
            let first_out = plain[at..]
                .iter()
                .position(|s| !in_cube(s.cell))
                .map_or(plain.len(), |i| at + i);
            assert_eq!(after_leap, plain[first_out..], "ray {k}");
            leaps += 1;
        }
        assert!(leaps > 150, "only {leaps} rays leapt");
    }
}
