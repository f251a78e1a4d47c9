//! How far each macro-cell lies from the nearest visible one, so that a ray in empty space
//! leaps over a whole cube of invisible macro-cells at once instead of stepping through them
//! one by one (on a CT head in a bone transfer function, four of five macro-cells a ray crosses
//! are empty, and stepping through them cost a third of the frame).

/// Largest distance kept: beyond it a leap is long enough that a longer one saves little, and
/// the transform's cost grows with it.
pub const MAX_LEAP: u8 = 16;

/// The Chebyshev (L∞) distance, in macro-cells, from each cell of a `dims` grid (x fastest) to
/// the nearest cell where `visible` is true, capped at [`MAX_LEAP`]. A cell at distance `d`
/// is the centre of a cube of `2d - 1` cells a side holding no visible cell.
///
/// The L∞ distance is separable (the minimum over cells of a maximum over axes), so it is
/// three passes of a one-dimensional transform, each along one axis.
pub fn chebyshev_distance(dims: [usize; 3], visible: &[bool]) -> Vec<u8> {
    assert_eq!(visible.len(), dims.iter().product::<usize>());
    let far = MAX_LEAP;
    let mut dist: Vec<u8> = visible.iter().map(|&v| if v { 0 } else { far }).collect();
    let strides = [1, dims[0], dims[0] * dims[1]];
    let mut line = Vec::new();
    for axis in 0..3 {
        let n = dims[axis];
        let other = [(axis + 1) % 3, (axis + 2) % 3];
        for i in 0..dims[other[0]] {
            for j in 0..dims[other[1]] {
                let start = i * strides[other[0]] + j * strides[other[1]];
                line.clear();
                line.extend((0..n).map(|k| dist[start + k * strides[axis]]));
                for (k, out) in min_max_line(&line, far).into_iter().enumerate() {
                    dist[start + k * strides[axis]] = out;
                }
            }
        }
    }
    dist
}

/// `out[k] = min over p of max(|k - p|, f[p])`, capped at `far`: only p within `far` of k can
/// beat the cap, so the work is bounded by `far` per entry.
fn min_max_line(f: &[u8], far: u8) -> Vec<u8> {
    let n = f.len();
    let reach = far as usize;
    (0..n)
        .map(|k| {
            let (lo, hi) = (k.saturating_sub(reach), (k + reach).min(n - 1));
            (lo..=hi)
                .map(|p| (k.abs_diff(p) as u8).max(f[p]))
                .min()
                .unwrap_or(far)
                .min(far)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition, by brute force over every pair of cells.
    fn brute_force(dims: [usize; 3], visible: &[bool]) -> Vec<u8> {
        let at = |i: usize| [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
        (0..visible.len())
            .map(|i| {
                (0..visible.len())
                    .filter(|&j| visible[j])
                    .map(|j| {
                        let (a, b) = (at(i), at(j));
                        (0..3).map(|x| a[x].abs_diff(b[x])).max().unwrap()
                    })
                    .min()
                    .map_or(MAX_LEAP, |d| d.min(MAX_LEAP as usize) as u8)
            })
            .collect()
    }

    #[test]
    fn matches_the_definition_on_scattered_and_empty_grids() {
        let dims = [7, 5, 23];
        let n: usize = dims.iter().product();
        // A fixed scatter of visible cells (a multiplicative hash, no dependency on a RNG).
        let scattered: Vec<bool> = (0..n)
            .map(|i| (i as u32).wrapping_mul(2654435761) % 97 < 3)
            .collect();
        assert!(scattered.iter().any(|&v| v));
        assert_eq!(
            chebyshev_distance(dims, &scattered),
            brute_force(dims, &scattered)
        );
        let empty = vec![false; n];
        assert!(chebyshev_distance(dims, &empty)
            .iter()
            .all(|&d| d == MAX_LEAP));
        let full = vec![true; n];
        assert!(chebyshev_distance(dims, &full).iter().all(|&d| d == 0));
    }

    #[test]
    fn a_single_visible_cell_is_the_centre_of_nested_cubes() {
        let dims = [40, 3, 1];
        let mut visible = vec![false; 120];
        visible[40 + 2] = true;
        let d = chebyshev_distance(dims, &visible);
        assert_eq!(d[42], 0);
        assert_eq!(d[0], 2);
        assert_eq!(d[2], 1);
        assert_eq!(d[80 + 39], 16);
        assert_eq!(d[80 + 12], 10);
    }
}
