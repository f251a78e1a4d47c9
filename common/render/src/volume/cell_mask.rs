//! Which voxel cells a transfer function can show, one bit per cell, brick by brick.
//!
//! The macro-cells skip what is empty in blocks of 8³ cells, but a macro-cell that holds any
//! bone is marched whole: on a CT head in a bone transfer function, five of six samples taken
//! in visible macro-cells are of soft tissue or air, and each cost eight loads, an
//! interpolation and a table lookup to add nothing. With a bit per cell, a sample in an
//! invisible cell costs the cell's position and one bit test.
//!
//! The bits depend on where the transfer function's opacity is non-zero, which no step
//! changes (`1 - (1 - a)^s` is zero exactly where `a` is), so one mask serves the coarse and
//! the full step. A brick's bits are made the first time a ray needs them: a frame touches only
//! the bricks its visible macro-cells lie in, and a new transfer function costs nothing up
//! front.

use super::bricks::{BrickView, CELL_WORDS};
use super::transfer::TransferTable;
use std::sync::OnceLock;
use tessera_model::volume_params::TransferFunction;

/// One bit per cell of every brick: set where the cell may show something.
#[derive(Debug)]
pub struct CellMask {
    transfer: TransferFunction,
    /// The missing-data colour (None: missing data is transparent, its cells shown only for
    /// their other corners).
    missing_color: Option<[f32; 3]>,
    /// The transfer function at the reference step: what decides visibility.
    table: Option<TransferTable>,
    bricks: Vec<OnceLock<Box<[u64; CELL_WORDS]>>>,
}

impl CellMask {
    /// The mask of `transfer` over a volume with values in `range` and `bricks` bricks, its
    /// missing data drawn in `missing_color` if there is one.
    pub fn new(
        transfer: TransferFunction,
        missing_color: Option<[f32; 3]>,
        range: (f32, f32),
        bricks: usize,
    ) -> Self {
        CellMask {
            transfer,
            missing_color,
            table: Some(TransferTable::new(&transfer, range, 1.0).with_missing(missing_color)),
            bricks: (0..bricks).map(|_| OnceLock::new()).collect(),
        }
    }

    /// A mask with every cell set, for tests that skipping changes nothing.
    #[cfg(test)]
    pub fn everything(transfer: TransferFunction, bricks: usize) -> Self {
        let all = || OnceLock::from(Box::new([u64::MAX; CELL_WORDS]));
        CellMask {
            transfer,
            missing_color: None,
            table: None,
            bricks: (0..bricks).map(|_| all()).collect(),
        }
    }

    /// What the mask was made for: the transfer function and the missing-data colour.
    pub fn made_for(&self) -> (&TransferFunction, Option<[f32; 3]>) {
        (&self.transfer, self.missing_color)
    }

    /// The bits of `brick`, made now if no ray has needed them yet.
    #[inline]
    pub fn of_brick(&self, brick: &BrickView) -> &[u64; CELL_WORDS] {
        self.bricks[brick.index()].get_or_init(|| {
            let table = self.table.as_ref().expect("a mask without a table is full");
            brick.cells_where(|range, missing| {
                table.any_visible(range) || (missing && table.shows_missing())
            })
        })
    }
}

/// Whether bit `bit` of `mask` is set.
#[inline(always)]
pub fn is_set(mask: &[u64; CELL_WORDS], bit: usize) -> bool {
    mask[bit / 64] >> (bit % 64) & 1 == 1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::bricks::{cell_bit, Bricks, BRICK_CELLS};
    use glam::UVec3;
    use tessera_model::volume_params::{TransferDomain, TransferPoint};

    #[test]
    fn a_cell_is_set_exactly_where_its_corners_reach_a_visible_value() {
        // 40 x 35 x 3 samples: two bricks along x and y, the second ones partial.
        let dims = [40, 35, 3];
        let values: Vec<f32> = (0..dims.iter().product::<usize>())
            .map(|i| ((i % 40) as f32 * 0.37 + (i / 40 % 35) as f32 * 0.11).sin())
            .collect();
        let bricks = Bricks::new(dims, &values);
        let p = |value, opacity| TransferPoint {
            value,
            color: [1.0; 3],
            opacity,
        };
        let transfer =
            TransferFunction::new(TransferDomain::Data, &[p(0.6, 0.0), p(0.9, 1.0)]).unwrap();
        let mask = CellMask::new(transfer, None, (-1.0, 1.0), 4);
        let table = TransferTable::new(&transfer, (-1.0, 1.0), 1.0);
        let (mut set, mut clear) = (0, 0);
        for z in 0..2 {
            for y in 0..34 {
                for x in 0..39 {
                    let corners = bricks.corners([x, y, z]);
                    let lo = corners.iter().copied().fold(f32::INFINITY, f32::min);
                    let hi = corners.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                    let view = bricks.brick_of([x, y, z]);
                    let local = [x, y, z].map(|i| i % BRICK_CELLS);
                    assert_eq!(
                        view.corners(UVec3::new(
                            local[0] as u32,
                            local[1] as u32,
                            local[2] as u32
                        )),
                        corners
                    );
                    let bit = is_set(mask.of_brick(&view), cell_bit(local));
                    assert_eq!(bit, table.any_visible((lo, hi)), "cell {x} {y} {z}");
                    if bit {
                        set += 1
                    } else {
                        clear += 1
                    }
                }
            }
        }
        assert!(set > 100 && clear > 100, "{set} set, {clear} clear");
    }
}
