//! A volume ready to trace: its bricks and min/max grid, the map from render coordinates to
//! its index space, and the two ways a ray sees it: composited through the transfer function,
//! or stopped at the first direct iso-surface.

use super::bricks::{
    trilinear, trilinear_gradient, whole4, BrickSource, Bricks, MinMaxGrid, BRICK_CELLS,
    MACRO_CELLS,
};
use super::cell_mask::{is_set, CellMask};
use super::empty_space::chebyshev_distance;
use super::grid_walk::{clip_to_box, GridWalk, IndexRay, Segment};
use super::transfer::TransferTable;
use super::Volume;
use glam::{DMat3, DVec3, Mat3, Vec3, Vec4};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};
use tessera_model::local_origin::RenderFromWorld;
use tessera_model::volume_params::{TransferFunction, VolumeParams};

/// Composited opacity past which a ray stops: what lies behind shows by less than this.
pub const OPAQUE_ENOUGH: f32 = 0.9995;
/// The smallest step allowed, in reference steps: below it a frame would take minutes.
pub const MIN_STEP_FRACTION: f32 = 1.0 / 256.0;
/// Most samples one ray takes, whatever the step: every loop is bounded.
const MAX_SAMPLES_PER_RAY: u32 = 1 << 22;

/// What the transfer function and step of a frame make of the volume.
#[derive(Debug)]
pub struct FrameTables {
    key: (TransferFunction, f32, Option<[f32; 3]>),
    /// The distance between samples along a ray, in render units ([`PreparedVolume::step`]).
    pub step: f32,
    /// The transfer function as a table over the volume's range, its opacities corrected for
    /// `step`.
    pub table: TransferTable,
    /// Per macro-cell: how far (in macro-cells, L∞) the nearest one with a visible value is;
    /// 0 where it has one itself.
    leap: Vec<u8>,
    /// Per voxel cell: whether the transfer function can show anything in it.
    cells: Arc<CellMask>,
}

/// A volume in render coordinates, bricked, with its min/max grid.
///
/// # Examples
///
/// ```
/// use tessera_render::volume::{PreparedVolume, Replicated, Volume, VoxelType};
/// use tessera_model::local_origin::RenderFromWorld;
/// use tessera_model::volume_params::VolumeParams;
/// use glam::Vec3;
///
/// let v = Volume::new([2, 2, 2], [1.0; 3], [0.0; 3], VoxelType::F32, vec![0., 1., 0., 1., 0., 1., 0., 1.])?;
/// let prepared = PreparedVolume::new(&v, &RenderFromWorld::IDENTITY);
/// // The surface where the value is 0.5 is the plane x = 0.5.
/// let hit = prepared.iso_hit(&[0.5], (Vec3::new(-1.0, 0.5, 0.5), Vec3::X), (0.0, 10.0), &mut Replicated);
/// assert!((hit.unwrap().0 - 1.5).abs() < 1e-5);
/// let tables = prepared.tables(&VolumeParams::DEFAULT);
/// let rgba = prepared.composite(&tables, (Vec3::new(-1.0, 0.5, 0.5), Vec3::X), (0.0, 10.0), &mut Replicated);
/// assert!(rgba[3] > 0.0 && rgba[3] < 1.0);
/// # Ok::<(), tessera_render::volume::VolumeError>(())
/// ```
pub struct PreparedVolume {
    bricks: Bricks,
    minmax: MinMaxGrid,
    placement: Placement,
    frame: Mutex<Option<Arc<FrameTables>>>,
    /// The cell mask of the last transfer function, kept across steps (it does not depend on
    /// them).
    cell_mask: Mutex<Option<Arc<CellMask>>>,
}

/// Where a prepared volume lies in render coordinates and what a ray needs to know of it
/// besides its samples: what a render node of a volume in shared memory holds whole, as the
/// replicated volume computed it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Samples along each axis (the padding to two included).
    dims: [usize; 3],
    index_from_render: Mat3,
    index_offset: Vec3,
    /// Transpose of `index_from_render`: takes an index-space gradient to render space.
    gradient_to_render: Mat3,
    extent: [f32; 3],
    range: (f32, f32),
    /// The smallest voxel spacing: what transfer-function opacities are given per.
    reference_step: f32,
    corners: [Vec3; 8],
}

/// What every render node of a volume in shared memory holds whole: where it lies and its
/// min/max grid (1/512 of the samples). The bricks are blocks.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SharedVolume {
    /// See [`Placement`].
    pub placement: Placement,
    /// The macro-cells' ranges, as the whole volume gives them.
    pub minmax: MinMaxGrid,
    /// Which of the layout's bricks is this volume's brick 0: 0 for a volume, `s × b` for
    /// step `s` of a series of `b` bricks a step.
    #[serde(default)]
    pub first_brick: u32,
}

impl Placement {
    /// Samples along each axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Cells along each axis (one fewer than samples).
    pub fn cells(&self) -> [usize; 3] {
        self.dims.map(|d| d - 1)
    }

    fn new(volume: &Volume, dims: [usize; 3], origin: [f64; 3], frame: &RenderFromWorld) -> Self {
        let axes = volume.axes().map(DVec3::from_array);
        let render_from_index = DMat3::from_cols(axes[0], axes[1], axes[2]);
        let index_from_render = render_from_index.inverse();
        let origin_render = DVec3::from_array(origin) - frame.world_origin;
        let index_offset = -(index_from_render * origin_render);
        let extent = dims.map(|d| (d - 1) as f32);
        let corners = std::array::from_fn(|i| {
            let idx = DVec3::new(
                if i & 1 == 1 { extent[0] as f64 } else { 0.0 },
                if i & 2 == 2 { extent[1] as f64 } else { 0.0 },
                if i & 4 == 4 { extent[2] as f64 } else { 0.0 },
            );
            (origin_render + render_from_index * idx).as_vec3()
        });
        let spacing = volume.spacing();
        Placement {
            dims,
            index_from_render: index_from_render.as_mat3(),
            index_offset: index_offset.as_vec3(),
            gradient_to_render: index_from_render.transpose().as_mat3(),
            extent,
            range: volume.range(),
            reference_step: spacing[0].min(spacing[1]).min(spacing[2]) as f32,
            corners,
        }
    }
}

impl SharedVolume {
    /// Bytes a render node holds of this volume besides its bricks, at most: the min/max grid
    /// and the per-frame leap table (9 and 1 bytes a macro-cell), and a cell mask per brick
    /// (one bit a cell, made as rays reach the brick). A 2 GiB volume's came to 74 MiB, which
    /// out of core took its render nodes 10-20 MiB past their budgets until it was counted.
    pub fn held_besides_bricks(&self) -> u64 {
        let per_brick = (super::bricks::CELL_WORDS * 8 + 16) as u64;
        self.summary_bytes() + self.brick_count() as u64 * per_brick
    }

    /// How many bricks the volume is cut into.
    pub fn brick_count(&self) -> usize {
        let cells = self.placement.cells();
        cells.iter().map(|c| c.div_ceil(BRICK_CELLS)).product()
    }

    /// Bytes of the min/max grid and the per-frame leap table (9 and 1 bytes a macro-cell):
    /// what a node holds of a series' step it does not show.
    pub fn summary_bytes(&self) -> u64 {
        self.minmax.ranges().len() as u64 * 10
    }
}

impl PreparedVolume {
    /// Bricks `volume` and its min/max grid, placed in the render coordinates of `frame` (the
    /// scene's [`crate::scene::Scene::render_from_world`]).
    pub fn new(volume: &Volume, frame: &RenderFromWorld) -> Self {
        let (dims, values, origin) = padded(volume);
        let bricks = Bricks::new(dims, &values);
        let minmax = MinMaxGrid::new(&bricks);
        let placement = Placement::new(volume, dims, origin, frame);
        PreparedVolume::from_parts(bricks, minmax, placement)
    }

    /// A volume whose bricks are in shared memory, read through a render thread's
    /// [`BrickSource`] (`crate::dsm::DsmReader`).
    pub fn shared(volume: SharedVolume) -> Self {
        let bricks = Bricks::shared(volume.placement.dims, volume.first_brick);
        PreparedVolume::from_parts(bricks, volume.minmax, volume.placement)
    }

    /// What a render node of this volume in shared memory holds whole.
    pub fn to_shared(&self) -> SharedVolume {
        SharedVolume {
            placement: self.placement.clone(),
            minmax: self.minmax.clone(),
            first_brick: 0,
        }
    }

    fn from_parts(bricks: Bricks, minmax: MinMaxGrid, placement: Placement) -> Self {
        PreparedVolume {
            bricks,
            minmax,
            placement,
            frame: Mutex::new(None),
            cell_mask: Mutex::new(None),
        }
    }

    /// The eight corners of the volume's box, in render coordinates.
    pub fn corners(&self) -> [Vec3; 8] {
        self.placement.corners
    }

    /// The samples, in bricks.
    pub fn bricks(&self) -> &Bricks {
        &self.bricks
    }

    /// The smallest voxel spacing, in render units: the step transfer-function opacities are given
    /// for, and half of it the default marching step.
    pub fn reference_step(&self) -> f32 {
        self.placement.reference_step
    }

    /// The step a frame with `params` marches at, in render units (the coarsening of a moving
    /// view included).
    pub fn step(&self, params: &VolumeParams) -> f32 {
        let floor = self.placement.reference_step * MIN_STEP_FRACTION;
        let full = if params.step > 0.0 {
            params.step.max(floor)
        } else {
            self.placement.reference_step * 0.5
        };
        full * params.coarsen
    }

    /// The table and visible macro-cells for `params`, made once per transfer function and
    /// step and shared by every packet of the frames that use them.
    pub fn tables(&self, params: &VolumeParams) -> Arc<FrameTables> {
        let step = self.step(params);
        let key = (params.transfer, step, params.missing_color);
        let mut cached = self.frame.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(tables) = cached.as_ref().filter(|t| t.key == key) {
            return tables.clone();
        }
        let table = TransferTable::new(
            &params.transfer,
            self.placement.range,
            step as f64 / self.placement.reference_step as f64,
        )
        .with_missing(params.missing_color);
        let ranges = self.minmax.ranges().iter().zip(self.minmax.missing());
        let visible: Vec<bool> = ranges
            .map(|(&r, &missing)| table.any_visible(r) || (missing && table.shows_missing()))
            .collect();
        let tables = Arc::new(FrameTables {
            key,
            step,
            table,
            leap: chebyshev_distance(self.minmax.dims(), &visible),
            cells: self.cell_mask(&params.transfer, params.missing_color),
        });
        *cached = Some(tables.clone());
        tables
    }

    fn cell_mask(&self, transfer: &TransferFunction, missing: Option<[f32; 3]>) -> Arc<CellMask> {
        let mut cached = self.cell_mask.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(mask) = cached
            .as_ref()
            .filter(|m| m.made_for() == (transfer, missing))
        {
            return mask.clone();
        }
        let bricks = self.bricks.brick_counts().iter().product();
        let mask = Arc::new(CellMask::new(
            *transfer,
            missing,
            self.placement.range,
            bricks,
        ));
        *cached = Some(mask.clone());
        mask
    }

    fn index_ray(&self, origin: Vec3, dir: Vec3) -> IndexRay {
        IndexRay {
            origin: (self.placement.index_from_render * origin + self.placement.index_offset)
                .to_array(),
            dir: (self.placement.index_from_render * dir).to_array(),
        }
    }

    /// The value at index-space point `p` (clamped into the grid); None where its brick is
    /// not here.
    #[inline]
    fn sample(&self, p: [f32; 3], source: &mut impl BrickSource) -> Option<f32> {
        let (cell, u) = self.cell_of(p);
        Some(trilinear(&self.bricks.corners_in(cell, source)?, u))
    }

    #[inline]
    fn cell_of(&self, p: [f32; 3]) -> ([usize; 3], [f32; 3]) {
        let cells = self.bricks.cells();
        let mut cell = [0usize; 3];
        let mut u = [0f32; 3];
        for a in 0..3 {
            let x = p[a].clamp(0.0, self.placement.extent[a]);
            let c = (x as usize).min(cells[a] - 1);
            cell[a] = c;
            u[a] = x - c as f32;
        }
        (cell, u)
    }

    fn macro_leap(&self, tables: &FrameTables, m: [usize; 3]) -> u8 {
        let d = self.minmax.dims();
        tables.leap[(m[2] * d[1] + m[1]) * d[0] + m[0]]
    }

    fn macro_walk(&self, ray: &IndexRay, (t0, t1): (f32, f32)) -> GridWalk {
        GridWalk::new(ray, MACRO_CELLS as f32, self.minmax.dims(), t0, t1)
    }

    /// Front-to-back composite (premultiplied colour, opacity) of the volume along
    /// `origin + t · dir` for `t` in `interval`, sampled at `t = k · step`. Macro-cells the
    /// transfer function makes invisible are skipped whole, and a cube of them at once where
    /// the ray is far from anything visible; the ray stops once [`OPAQUE_ENOUGH`]. A brick
    /// `source` does not have adds nothing (the trace is void).
    pub fn composite(
        &self,
        tables: &FrameTables,
        (origin, dir): (Vec3, Vec3),
        interval: (f32, f32),
        source: &mut impl BrickSource,
    ) -> [f32; 4] {
        let ray = self.index_ray(origin, dir);
        let mut acc = Vec4::ZERO;
        let Some(span) = clip_to_box(&ray, self.placement.extent, interval.0, interval.1) else {
            return [0.0; 4];
        };
        let step = tables.step;
        let (origin_index, dir_index) = (Vec3::from_array(ray.origin), Vec3::from_array(ray.dir));
        let mut budget = MAX_SAMPLES_PER_RAY;
        let mut walk = self.macro_walk(&ray, span);
        while let Some(Segment { cell, t0, t1 }) = walk.next() {
            match self.macro_leap(tables, cell) {
                0 => {}
                1 => continue,
                far => {
                    walk.leap_out_of(cell, far as usize - 1);
                    continue;
                }
            }
            // The samples k · step in t0..t1, counted before the loop so that it runs without a
            // test of t (and without `ceil`, a libm call on baseline x86-64).
            let first = first_sample_at(t0, step);
            let end = first_sample_at(t1, step).min(first + budget as i64);
            budget -= (end - first).max(0) as u32;
            if self.march_macro_cell(
                tables,
                (origin_index, dir_index),
                (cell, first..end),
                &mut acc,
                source,
            ) {
                break;
            }
        }
        acc.to_array()
    }

    /// Composites the samples `ks` (at `t = k · step`) of macro-cell `cell` into `acc`; true
    /// once it is [`OPAQUE_ENOUGH`].
    ///
    /// Four samples at a time: located, tested against the cell mask, and where any may show,
    /// interpolated and looked up (independent work, four lanes wide), then composited one by
    /// one (each depends on the one before). Lanes past the end are located (clamped into the
    /// brick) and dropped; lanes in invisible cells beside visible ones add exactly zero.
    #[inline(always)]
    fn march_macro_cell(
        &self,
        tables: &FrameTables,
        (origin, dir): (Vec3, Vec3),
        (cell, ks): ([usize; 3], std::ops::Range<i64>),
        acc: &mut Vec4,
        source: &mut impl BrickSource,
    ) -> bool {
        // A macro-cell lies in one brick (8 divides 32): found once per macro-cell.
        let Some(brick) = self.bricks.brick_in(cell.map(|m| m * MACRO_CELLS), source) else {
            return false;
        };
        let mask = tables.cells.of_brick(&brick);
        let edge = BRICK_CELLS as f32;
        for k in ks.clone().step_by(4) {
            let lanes = (ks.end - k).min(4) as usize;
            let t = Vec4::from_array([0, 1, 2, 3].map(|i| (k + i) as f32 * tables.step));
            let at = brick.locate4(origin, dir, t);
            let [cx, cy, cz] = at.cell;
            // Exact in f32 (below 2^15): the cells' bits.
            let bits = whole4((cz * edge + cy) * edge + cx);
            if !bits[..lanes].iter().any(|&b| is_set(mask, b as usize)) {
                continue;
            }
            for e in &tables.table.lookup4(brick.interpolate4(&at))[..lanes] {
                *acc += (1.0 - acc.w) * *e;
                if acc.w >= OPAQUE_ENOUGH {
                    return true;
                }
            }
        }
        false
    }

    /// [`PreparedVolume::composite`] without skipping: every sample of the interval, for tests
    /// that skipping changes nothing.
    #[cfg(test)]
    pub(crate) fn composite_every_sample(
        &self,
        tables: &FrameTables,
        origin: Vec3,
        dir: Vec3,
        interval: (f32, f32),
    ) -> [f32; 4] {
        let everything = FrameTables {
            key: tables.key,
            step: tables.step,
            table: tables.table.clone(),
            leap: vec![0; tables.leap.len()],
            cells: Arc::new(CellMask::everything(
                tables.key.0,
                self.bricks.brick_counts().iter().product(),
            )),
        };
        let mut source = super::bricks::Replicated;
        self.composite(&everything, (origin, dir), interval, &mut source)
    }

    /// The nearest crossing of any of `iso` along the ray within `interval`: its `t` and which
    /// value it is. Exact per cell: the trilinear field along the ray is a cubic, split where
    /// it turns so that each piece crosses at most once, so no thin crossing is skipped. A
    /// cell whose brick `source` does not have is passed (the trace is void).
    pub fn iso_hit(
        &self,
        iso: &[f32],
        (origin, dir): (Vec3, Vec3),
        interval: (f32, f32),
        source: &mut impl BrickSource,
    ) -> Option<(f32, u8)> {
        if iso.is_empty() {
            return None;
        }
        let ray = self.index_ray(origin, dir);
        let span = clip_to_box(&ray, self.placement.extent, interval.0, interval.1)?;
        let cells = self.bricks.cells();
        for outer in self.macro_walk(&ray, span) {
            let (lo, hi) = self.minmax.range(outer.cell);
            if !iso.iter().any(|&v| lo <= v && v <= hi) {
                continue;
            }
            for seg in GridWalk::new(&ray, 1.0, cells, outer.t0, outer.t1) {
                let Some(corners) = self.bricks.corners_in(seg.cell, source) else {
                    continue;
                };
                if let Some(hit) = cell_crossing(&corners, &ray, &seg, iso) {
                    return Some(hit);
                }
            }
        }
        None
    }

    /// The unit normal of the field at render-space `point` (the gradient of the trilinear
    /// interpolant of its cell); `fallback` where the field is flat, or its brick not here.
    pub fn normal_at(&self, point: Vec3, fallback: Vec3, source: &mut impl BrickSource) -> Vec3 {
        let p = (self.placement.index_from_render * point + self.placement.index_offset).to_array();
        let (cell, u) = self.cell_of(p);
        let Some(corners) = self.bricks.corners_in(cell, source) else {
            return fallback;
        };
        let g = Vec3::from_array(trilinear_gradient(&corners, u));
        // Scaled to a largest component of 1 first: the gradient of values of 10³⁰ squares to
        // past f32's range, of 10⁻³⁰ to below it, and either normalised to zero (flat shading).
        let g = g / g.abs().max_element();
        let n = (self.placement.gradient_to_render * g).normalize_or_zero();
        if n == Vec3::ZERO || !n.is_finite() {
            fallback
        } else {
            n
        }
    }

    /// What a viewer sees of the volume along the ray within `interval`: its `t` and the value
    /// there. With iso-values, the first iso-surface; through the transfer function, the first
    /// sample at which the ray's composited opacity reaches one half. None where neither is.
    /// Of a volume in this process's memory (the master's, which keeps one for the probe).
    pub fn probe(
        &self,
        params: &VolumeParams,
        origin: Vec3,
        dir: Vec3,
        interval: (f32, f32),
    ) -> Option<(f32, f32)> {
        let at = |t: f32| self.value_at(origin + dir * t);
        let mut source = super::bricks::Replicated;
        if !params.iso.is_empty() {
            let iso = params.iso.as_slice();
            let (t, _) = self.iso_hit(iso, (origin, dir), interval, &mut source)?;
            return Some((t, at(t)?));
        }
        let tables = self.tables(params);
        let ray = self.index_ray(origin, dir);
        let (t0, t1) = clip_to_box(&ray, self.placement.extent, interval.0, interval.1)?;
        let step = tables.step;
        let mut alpha = 0f32;
        // The very samples `composite` takes.
        let first = first_sample_at(t0, step);
        let end = first_sample_at(t1, step).min(first + MAX_SAMPLES_PER_RAY as i64);
        for k in first..end {
            let t = k as f32 * step;
            let p = std::array::from_fn(|a| ray.origin[a] + ray.dir[a] * t);
            let value = self.sample(p, &mut source)?;
            alpha += (1.0 - alpha) * tables.table.lookup(value)[3];
            if alpha >= 0.5 {
                return Some((t, value));
            }
        }
        None
    }

    /// The value at render-space `point`, or None outside the volume, of a volume in this
    /// process's memory.
    pub fn value_at(&self, point: Vec3) -> Option<f32> {
        let p = (self.placement.index_from_render * point + self.placement.index_offset).to_array();
        let inside = (0..3).all(|a| (0.0..=self.placement.extent[a]).contains(&p[a]));
        inside
            .then(|| self.sample(p, &mut super::bricks::Replicated))
            .flatten()
    }
}

/// The first k with `k as f32 * step >= t`: the same comparison on either side of a segment
/// boundary, so every sample falls in exactly one segment.
#[inline]
fn first_sample_at(t: f32, step: f32) -> i64 {
    let mut k = (t / step) as i64 - 1;
    while (k as f32) * step < t {
        k += 1;
    }
    k
}

/// The first crossing of any of `iso` inside one cell, with `t` on the whole ray.
fn cell_crossing(
    corners: &[f32; 8],
    ray: &IndexRay,
    seg: &Segment,
    iso: &[f32],
) -> Option<(f32, u8)> {
    // A cell that touches missing data has no field to cross: the surface ends open there.
    if corners.iter().any(|v| v.is_nan()) {
        return None;
    }
    let (lo, hi) = corners
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let length = (seg.t1 - seg.t0) as f64;
    // The field along the ray as a cubic in s = t - t0, in f64 (the cell's own coordinates,
    // so large t far from the eye costs no digits).
    let a: [f64; 3] = std::array::from_fn(|k| {
        (ray.origin[k] as f64 + ray.dir[k] as f64 * seg.t0 as f64) - seg.cell[k] as f64
    });
    let b: [f64; 3] = ray.dir.map(|d| d as f64);
    let cubic = field_cubic(corners, a, b);
    let mut best: Option<(f64, u8)> = None;
    for (index, &value) in iso.iter().enumerate() {
        if value < lo || value > hi {
            continue;
        }
        let mut c = cubic;
        c[0] -= value as f64;
        if let Some(s) = first_root(c, length) {
            if best.is_none_or(|(t, _)| s < t) {
                best = Some((s, index as u8));
            }
        }
    }
    best.map(|(s, i)| (seg.t0 + s as f32, i))
}

/// Coefficients `[c0, c1, c2, c3]` of the trilinear field at `a + s · b` (cell coordinates).
fn field_cubic(corners: &[f32; 8], a: [f64; 3], b: [f64; 3]) -> [f64; 4] {
    let mut c = [0f64; 4];
    for (i, &value) in corners.iter().enumerate() {
        // Each corner's weight is a product of three factors linear in s: p + s·q.
        let factor = |axis: usize| {
            if (i >> axis) & 1 == 1 {
                (a[axis], b[axis])
            } else {
                (1.0 - a[axis], -b[axis])
            }
        };
        let ((px, qx), (py, qy), (pz, qz)) = (factor(0), factor(1), factor(2));
        let v = value as f64;
        c[0] += v * px * py * pz;
        c[1] += v * (qx * py * pz + px * qy * pz + px * py * qz);
        c[2] += v * (qx * qy * pz + qx * py * qz + px * qy * qz);
        c[3] += v * qx * qy * qz;
    }
    c
}

fn eval_cubic(c: &[f64; 4], s: f64) -> f64 {
    ((c[3] * s + c[2]) * s + c[1]) * s + c[0]
}

/// The smallest root of the cubic `c` in `0..=length`: the interval is cut where the cubic's
/// derivative vanishes, each piece is monotonic, and a piece whose ends differ in sign holds
/// exactly one root, found by bisection.
fn first_root(c: [f64; 4], length: f64) -> Option<f64> {
    let mut knots = [0.0, length, length, length];
    let mut n = 1;
    // Roots of 3c3 s² + 2c2 s + c1.
    let (qa, qb, qc) = (3.0 * c[3], 2.0 * c[2], c[1]);
    let mut turning = [f64::NAN; 2];
    if qa.abs() > 1e-300 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            let root = disc.sqrt();
            // The stable form: no cancellation between -qb and the root.
            let q = -0.5 * (qb + qb.signum() * root);
            turning = [q / qa, if q != 0.0 { qc / q } else { f64::NAN }];
        }
    } else if qb.abs() > 1e-300 {
        turning[0] = -qc / qb;
    }
    turning.sort_by(|x, y| x.total_cmp(y));
    for s in turning {
        if s > 0.0 && s < length {
            knots[n] = s;
            n += 1;
        }
    }
    knots[n] = length;
    for w in knots[..=n].windows(2) {
        let (s0, s1) = (w[0], w[1]);
        let (g0, g1) = (eval_cubic(&c, s0), eval_cubic(&c, s1));
        if g0 == 0.0 {
            return Some(s0);
        }
        if g0.signum() != g1.signum() || g1 == 0.0 {
            return Some(bisect(&c, s0, s1, g0));
        }
    }
    None
}

fn bisect(c: &[f64; 4], mut lo: f64, mut hi: f64, g_lo: f64) -> f64 {
    let below = g_lo < 0.0;
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if (eval_cubic(c, mid) < 0.0) == below {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The volume's dimensions, samples and origin with every axis at least 2 samples long: an
/// axis of one sample becomes a slab one voxel thick around it, so a 1×1×1 volume is a cube.
fn padded(volume: &Volume) -> ([usize; 3], Vec<f32>, [f64; 3]) {
    let mut dims = volume.dims();
    let mut values = volume.values().to_vec();
    let mut origin = volume.origin();
    let axes = volume.axes();
    for a in 0..3 {
        if dims[a] != 1 {
            continue;
        }
        let mut wider = dims;
        wider[a] = 2;
        let mut out = Vec::with_capacity(values.len() * 2);
        for z in 0..wider[2] {
            for y in 0..wider[1] {
                for x in 0..wider[0] {
                    let mut src = [x, y, z];
                    src[a] = 0;
                    out.push(values[(src[2] * dims[1] + src[1]) * dims[0] + src[0]]);
                }
            }
        }
        for w in 0..3 {
            origin[w] -= 0.5 * axes[a][w];
        }
        dims = wider;
        values = out;
    }
    (dims, values, origin)
}
