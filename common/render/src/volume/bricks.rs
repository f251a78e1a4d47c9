//! A volume's samples held in bricks, and the min/max grid over them that empty-space skipping
//! reads.
//!
//! A brick covers [`BRICK_CELLS`]³ cells and stores their corner samples, 33³ with the
//! one-voxel apron on the high side shared with the next brick, so the eight corners of any cell
//! lie in one brick: trilinear interpolation and the iso-surface test never look at two bricks,
//! and a brick is a unit the distributed shared memory can move whole.

use glam::{UVec3, Vec3, Vec4};

/// Cells along each edge of a brick.
pub const BRICK_CELLS: usize = 32;
/// Cells along each edge of a macro-cell of the min/max grid.
pub const MACRO_CELLS: usize = 8;

/// Where one brick's samples start and how many it has along x and y.
#[derive(Clone, Copy, Debug)]
struct BrickSlot {
    offset: usize,
    nx: u32,
    ny: u32,
}

/// Samples of the largest brick, apron included.
pub const BRICK_SAMPLES: usize = (BRICK_CELLS + 1) * (BRICK_CELLS + 1) * (BRICK_CELLS + 1);

/// The samples of a grid of `cells` cells (`cells + 1` samples an axis), brick by brick: in
/// this process's memory, or in distributed shared memory, one brick a block, read through a
/// [`BrickSource`].
#[derive(Clone, Debug)]
pub struct Bricks {
    cells: [usize; 3],
    bricks: [usize; 3],
    slots: Vec<BrickSlot>,
    /// Every brick's samples, at its slot's offset; empty for bricks in shared memory.
    samples: Vec<f32>,
    /// Whether the samples are in shared memory (see [`Bricks::shared`]).
    shared: bool,
    /// For bricks in shared memory, the brick of the layout's brick blocks that is brick 0
    /// here: a series' step `s` of `b` bricks starts at `s × b`.
    first_shared: u32,
}

/// Where a volume tracer reads a brick's samples: a replicated volume's own array
/// ([`Replicated`]), or a render thread's blocks of distributed shared memory, where a brick
/// may not be here yet (`crate::dsm::DsmReader`).
pub trait BrickSource {
    /// The samples of brick `index` of `bricks` from its first on ([`Bricks::brick_len`] of
    /// them at least, x fastest), or None where they are not here: a trace that parks its misses has asked for them and
    /// what it traces is void (it is traced again once they landed).
    fn samples<'a>(&'a mut self, bricks: &'a Bricks, index: usize) -> Option<&'a [f32]>;
}

/// The [`BrickSource`] of a volume whose samples are in this process's memory.
#[derive(Clone, Copy, Debug, Default)]
pub struct Replicated;

impl BrickSource for Replicated {
    #[inline(always)]
    fn samples<'a>(&'a mut self, bricks: &'a Bricks, index: usize) -> Option<&'a [f32]> {
        Some(bricks.local_samples(index))
    }
}

impl Bricks {
    /// Bricks of `values`, `dims` samples in x-fastest order (each dimension at least 2).
    pub fn new(dims: [usize; 3], values: &[f32]) -> Self {
        assert!(values.len() == dims.iter().product::<usize>());
        let mut laid = Bricks::laid_out(dims);
        laid.samples.reserve_exact(values.len() + values.len() / 8);
        for (index, slot) in laid.slots.iter().enumerate() {
            let [bx, by] = [
                index % laid.bricks[0],
                index / laid.bricks[0] % laid.bricks[1],
            ];
            let b = [bx, by, index / (laid.bricks[0] * laid.bricks[1])];
            let first = b.map(|b| b * BRICK_CELLS);
            let n = brick_extent(laid.cells, b);
            debug_assert_eq!(slot.offset, laid.samples.len());
            for z in first[2]..first[2] + n[2] {
                for y in first[1]..first[1] + n[1] {
                    let row = (z * dims[1] + y) * dims[0] + first[0];
                    laid.samples.extend_from_slice(&values[row..row + n[0]]);
                }
            }
        }
        laid
    }

    /// The bricks of a grid of `dims` samples whose samples are in shared memory, brick `i`
    /// at the start of a block of its own (brick block `first + i`), laid out as
    /// [`Bricks::new`] lays them out.
    pub fn shared(dims: [usize; 3], first: u32) -> Self {
        Bricks {
            shared: true,
            first_shared: first,
            ..Bricks::laid_out(dims)
        }
    }

    /// For bricks in shared memory, which of the layout's bricks is brick 0 here.
    #[inline(always)]
    pub fn first_shared(&self) -> u32 {
        self.first_shared
    }

    /// The bricks of a grid of `dims` samples, each slot at the offset its samples take in
    /// order, no sample held yet.
    fn laid_out(dims: [usize; 3]) -> Self {
        assert!(dims.iter().all(|&d| d >= 2));
        let cells = dims.map(|d| d - 1);
        let bricks = cells.map(|c| c.div_ceil(BRICK_CELLS));
        let mut slots = Vec::with_capacity(bricks.iter().product());
        let mut offset = 0;
        for bz in 0..bricks[2] {
            for by in 0..bricks[1] {
                for bx in 0..bricks[0] {
                    let n = brick_extent(cells, [bx, by, bz]);
                    let (nx, ny) = (n[0] as u32, n[1] as u32);
                    slots.push(BrickSlot { offset, nx, ny });
                    offset += n.iter().product::<usize>();
                }
            }
        }
        Bricks {
            cells,
            bricks,
            slots,
            samples: Vec::new(),
            shared: false,
            first_shared: 0,
        }
    }

    /// Whether the samples are in shared memory (read through a render thread's blocks).
    pub fn is_shared(&self) -> bool {
        self.shared
    }

    /// How many bricks there are.
    pub fn count(&self) -> usize {
        self.slots.len()
    }

    /// Samples of brick `index`, x fastest, its apron included.
    pub fn brick_len(&self, index: usize) -> usize {
        let slot = self.slots[index];
        let bz = index / (self.bricks[0] * self.bricks[1]);
        let nz = (self.cells[2] - bz * BRICK_CELLS).min(BRICK_CELLS) + 1;
        slot.nx as usize * slot.ny as usize * nz
    }

    /// The samples from the first of brick `index` on, of bricks in this process's memory
    /// (empty for bricks in shared memory).
    #[inline(always)]
    pub fn local_samples(&self, index: usize) -> &[f32] {
        &self.samples[self.slots[index].offset.min(self.samples.len())..]
    }

    /// Cells along each axis.
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// Bricks along each axis.
    pub fn brick_counts(&self) -> [usize; 3] {
        self.bricks
    }

    /// Bytes of samples held (apron included).
    pub fn bytes(&self) -> usize {
        std::mem::size_of_val(&self.samples[..])
    }

    /// The brick holding cell `c` (each index below `cells`), of bricks in this process's
    /// memory.
    #[inline]
    pub fn brick_of(&self, c: [usize; 3]) -> BrickView<'_> {
        let index = self.brick_index(c);
        self.view(c, self.local_samples(index))
    }

    #[inline(always)]
    fn brick_index(&self, c: [usize; 3]) -> usize {
        let b = c.map(|i| i / BRICK_CELLS);
        (b[2] * self.bricks[1] + b[1]) * self.bricks[0] + b[0]
    }

    /// The brick holding cell `c` (each index below `cells`), its samples read from
    /// `source`; None where they are not here.
    #[inline(always)]
    pub fn brick_in<'a>(
        &'a self,
        c: [usize; 3],
        source: &'a mut impl BrickSource,
    ) -> Option<BrickView<'a>> {
        let index = self.brick_index(c);
        Some(self.view(c, source.samples(self, index)?))
    }

    /// The view of the brick holding cell `c`, its samples from the first on.
    #[inline(always)]
    fn view<'a>(&self, c: [usize; 3], samples: &'a [f32]) -> BrickView<'a> {
        let b = c.map(|i| i / BRICK_CELLS);
        let index = self.brick_index(c);
        let slot = self.slots[index];
        let (nx, ny) = (slot.nx as usize, slot.ny as usize);
        let nz = (self.cells[2] - b[2] * BRICK_CELLS).min(BRICK_CELLS) + 1;
        BrickView {
            index,
            samples: &samples[..nx * ny * nz],
            first: Vec3::from_array(b.map(|i| (i * BRICK_CELLS) as f32)),
            last_cell: UVec3::new(nx as u32 - 2, ny as u32 - 2, nz as u32 - 2),
            dy: nx,
            dz: nx * ny,
        }
    }

    /// The eight corner samples of cell `c` (each index below `cells`), bit 0 of the corner's
    /// number being +x, bit 1 +y, bit 2 +z, of bricks in this process's memory.
    #[inline]
    pub fn corners(&self, c: [usize; 3]) -> [f32; 8] {
        self.corners_in(c, &mut Replicated)
            .expect("a replicated brick is here")
    }

    /// [`Bricks::corners`], the samples read from `source`; None where they are not here.
    #[inline(always)]
    pub fn corners_in(&self, c: [usize; 3], source: &mut impl BrickSource) -> Option<[f32; 8]> {
        let index = self.brick_index(c);
        let slot = self.slots[index];
        let (nx, ny) = (slot.nx as usize, slot.ny as usize);
        let l = c.map(|i| i % BRICK_CELLS);
        let base = (l[2] * ny + l[1]) * nx + l[0];
        let s = source.samples(self, index)?;
        let (dy, dz) = (nx, nx * ny);
        Some([
            s[base],
            s[base + 1],
            s[base + dy],
            s[base + dy + 1],
            s[base + dz],
            s[base + dz + 1],
            s[base + dz + dy],
            s[base + dz + dy + 1],
        ])
    }
}

/// Samples along each axis of brick `b` of a grid of `cells` cells (apron included).
fn brick_extent(cells: [usize; 3], b: [usize; 3]) -> [usize; 3] {
    std::array::from_fn(|a| (cells[a] - b[a] * BRICK_CELLS).min(BRICK_CELLS) + 1)
}

/// The lanes of `v`, whole numbers in `0..2^23`, as integers: adding 2^23 places each in the
/// low mantissa bits exactly, so the conversion is an add and a subtract in the vector unit.
/// (`as` checks each lane for saturation one at a time; those checks were a tenth of a volume
/// frame.)
#[inline(always)]
pub fn whole4(v: Vec4) -> [u32; 4] {
    const SHIFT: f32 = 8_388_608.0;
    let bits: [u32; 4] = bytemuck::cast(v + Vec4::splat(SHIFT));
    bits.map(|b| b - SHIFT.to_bits())
}

/// Words of one bit per cell of a brick.
pub const CELL_WORDS: usize = BRICK_CELLS * BRICK_CELLS * BRICK_CELLS / 64;

/// The bit of brick-local cell `c` in [`BrickView::cells_where`]'s mask.
#[inline(always)]
pub fn cell_bit(c: [usize; 3]) -> usize {
    (c[2] * BRICK_CELLS + c[1]) * BRICK_CELLS + c[0]
}

/// Four points located in a brick, lane by lane: their cells (whole numbers) and positions
/// from the brick's first sample, each per axis.
#[derive(Clone, Copy, Debug)]
pub struct Lanes4 {
    pub cell: [Vec4; 3],
    pub position: [Vec4; 3],
}

/// One brick's samples, for sampling many points inside it without finding the brick each time.
#[derive(Clone, Copy, Debug)]
pub struct BrickView<'a> {
    index: usize,
    samples: &'a [f32],
    /// Index-space position of the brick's first sample.
    first: Vec3,
    /// Last cell index along each axis (samples - 2).
    last_cell: UVec3,
    dy: usize,
    dz: usize,
}

impl<'a> BrickView<'a> {
    /// The cell holding index-space point `p` (clamped into this brick) and the point's place in
    /// it (each in 0..1). Written per axis with glam rather than as loops over arrays, which
    /// the compiler kept in memory.
    #[inline(always)]
    pub fn locate(&self, p: Vec3) -> (UVec3, Vec3) {
        let x = p - self.first;
        // Truncation is floor for x >= 0, and below 0 both clamp to cell 0; `floor` is a
        // libm call on baseline x86-64 (no SSE4.1), and it was 8 % of a volume frame.
        let c = x.max(Vec3::ZERO).as_uvec3().min(self.last_cell);
        (c, (x - c.as_vec3()).clamp(Vec3::ZERO, Vec3::ONE))
    }

    /// [`BrickView::locate`] of the points `origin + dir · t` for four `t` (index space), four
    /// lanes wide with the same operations in the same order, so each lane is what the
    /// one-point path gives, bit for bit: the cells (as whole numbers in `f32`) and the
    /// positions relative to the brick, axis by axis. The place in the cell is left to
    /// [`BrickView::interpolate4`], so that points the cell mask rejects never compute it.
    #[inline(always)]
    pub fn locate4(&self, origin: Vec3, dir: Vec3, t: Vec4) -> Lanes4 {
        let axis = |a: usize| {
            let x = Vec4::splat(origin[a]) + Vec4::splat(dir[a]) * t - Vec4::splat(self.first[a]);
            // Truncation is floor here (x >= 0 after the max).
            let c = x
                .max(Vec4::ZERO)
                .trunc()
                .min(Vec4::splat(self.last_cell[a] as f32));
            (c, x)
        };
        let ((cx, x), (cy, y), (cz, z)) = (axis(0), axis(1), axis(2));
        Lanes4 {
            cell: [cx, cy, cz],
            position: [x, y, z],
        }
    }

    /// [`trilinear_at`] of four located points, as the one-point path computes it. Only the
    /// eight loads per lane are not vector operations.
    #[inline(always)]
    pub fn interpolate4(&self, at: &Lanes4) -> Vec4 {
        let [cx, cy, cz] = at.cell;
        let place = |a: usize| (at.position[a] - at.cell[a]).clamp(Vec4::ZERO, Vec4::ONE);
        let (ux, uy, uz) = (place(0), place(1), place(2));
        // Exact in f32: a brick has fewer than 2^24 samples.
        let base = cz * self.dz as f32 + cy * self.dy as f32 + cx;
        let base = whole4(base).map(|b| b as usize);
        let (dy, dz) = (self.dy, self.dz);
        let corner = |offset: usize| Vec4::from_array(base.map(|b| self.samples[b + offset]));
        let lerp = |a: Vec4, b: Vec4, t: Vec4| a + (b - a) * t;
        let x00 = lerp(corner(0), corner(1), ux);
        let x10 = lerp(corner(dy), corner(dy + 1), ux);
        let x01 = lerp(corner(dz), corner(dz + 1), ux);
        let x11 = lerp(corner(dz + dy), corner(dz + dy + 1), ux);
        lerp(lerp(x00, x10, uy), lerp(x01, x11, uy), uz)
    }

    /// This brick's number among the volume's bricks.
    pub fn index(&self) -> usize {
        self.index
    }

    /// One bit per cell of the brick ([`cell_bit`] numbers them): set where `visible` holds
    /// for the range of the cell's eight corners, which bounds every value interpolated in it,
    /// and whether a corner is missing data (NaN, which the range leaves out).
    pub fn cells_where(
        &self,
        visible: impl Fn((f32, f32), bool) -> bool,
    ) -> Box<[u64; CELL_WORDS]> {
        let mut bits = Box::new([0u64; CELL_WORDS]);
        for z in 0..=self.last_cell.z {
            for y in 0..=self.last_cell.y {
                for x in 0..=self.last_cell.x {
                    let corners = self.corners(UVec3::new(x, y, z));
                    let range = corners
                        .iter()
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                            (lo.min(v), hi.max(v))
                        });
                    if visible(range, corners.iter().any(|v| v.is_nan())) {
                        let bit = cell_bit([x, y, z].map(|i| i as usize));
                        bits[bit / 64] |= 1 << (bit % 64);
                    }
                }
            }
        }
        bits
    }

    /// The eight corners of the brick-local `cell`, numbered as [`Bricks::corners`] numbers them.
    #[inline(always)]
    pub fn corners(&self, cell: UVec3) -> [f32; 8] {
        let base = cell.z as usize * self.dz + cell.y as usize * self.dy + cell.x as usize;
        let s = &self.samples[base..base + self.dz + self.dy + 2];
        let (dy, dz) = (self.dy, self.dz);
        [
            s[0],
            s[1],
            s[dy],
            s[dy + 1],
            s[dz],
            s[dz + 1],
            s[dz + dy],
            s[dz + dy + 1],
        ]
    }
}

/// Trilinear interpolation of `corners` at `u` (each in 0..1) inside the cell.
#[inline]
pub fn trilinear(corners: &[f32; 8], u: [f32; 3]) -> f32 {
    trilinear_at(corners, Vec3::from_array(u))
}

/// [`trilinear`] with the place in the cell as a vector.
#[inline(always)]
pub fn trilinear_at(corners: &[f32; 8], u: Vec3) -> f32 {
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let x00 = lerp(corners[0], corners[1], u.x);
    let x10 = lerp(corners[2], corners[3], u.x);
    let x01 = lerp(corners[4], corners[5], u.x);
    let x11 = lerp(corners[6], corners[7], u.x);
    lerp(lerp(x00, x10, u.y), lerp(x01, x11, u.y), u.z)
}

/// The gradient of the trilinear interpolant of `corners` at `u`, in cell units.
pub fn trilinear_gradient(c: &[f32; 8], [x, y, z]: [f32; 3]) -> [f32; 3] {
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let dx = lerp(
        lerp(c[1] - c[0], c[3] - c[2], y),
        lerp(c[5] - c[4], c[7] - c[6], y),
        z,
    );
    let dy = lerp(
        lerp(c[2] - c[0], c[3] - c[1], x),
        lerp(c[6] - c[4], c[7] - c[5], x),
        z,
    );
    let dz = lerp(
        lerp(c[4] - c[0], c[5] - c[1], x),
        lerp(c[6] - c[2], c[7] - c[3], x),
        y,
    );
    [dx, dy, dz]
}

/// The smallest and largest sample of each macro-cell ([`MACRO_CELLS`]³ cells, corners
/// included, so a value on a shared face is in both cells' ranges).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MinMaxGrid {
    dims: [usize; 3],
    ranges: Vec<(f32, f32)>,
    /// Whether each macro-cell touches missing data (NaN), which its range leaves out.
    missing: Vec<bool>,
}

impl MinMaxGrid {
    /// The grid of bricks in this process's memory.
    pub fn new(bricks: &Bricks) -> Self {
        let cells = bricks.cells();
        let dims = cells.map(|c| c.div_ceil(MACRO_CELLS));
        let mut ranges = vec![(f32::INFINITY, f32::NEG_INFINITY); dims.iter().product()];
        let mut missing = vec![false; ranges.len()];
        for z in 0..cells[2] {
            for y in 0..cells[1] {
                for x in 0..cells[0] {
                    let m = [x, y, z].map(|i| i / MACRO_CELLS);
                    let i = (m[2] * dims[1] + m[1]) * dims[0] + m[0];
                    let r = &mut ranges[i];
                    for v in bricks.corners([x, y, z]) {
                        *r = (r.0.min(v), r.1.max(v));
                        missing[i] |= v.is_nan();
                    }
                }
            }
        }
        MinMaxGrid {
            dims,
            ranges,
            missing,
        }
    }

    /// Macro-cells along each axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The smallest and largest sample of macro-cell `m`.
    #[inline]
    pub fn range(&self, m: [usize; 3]) -> (f32, f32) {
        self.ranges[(m[2] * self.dims[1] + m[1]) * self.dims[0] + m[0]]
    }

    /// Every macro-cell's range, x fastest.
    pub fn ranges(&self) -> &[(f32, f32)] {
        &self.ranges
    }

    /// Whether each macro-cell touches missing data, in the order of [`MinMaxGrid::ranges`].
    pub fn missing(&self) -> &[bool] {
        &self.missing
    }
}
