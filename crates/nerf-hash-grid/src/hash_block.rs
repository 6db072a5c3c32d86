//! The fused hash encoding's inner loops ([`crate::hash_grid`]): one level of a block
//! of [`BLOCK`] points at a time. The corner rows and trilinear weights of the block are
//! computed in structure-of-arrays form, a lane per point, which the compiler vectorises (copies
//! for AVX-512 and AVX2 are picked at run time); the gathers (forward) and scatters (backward)
//! then walk the block point by point, corners in order, so that every sum is taken in the same
//! order as [`Level::corners`] with [`crate::hash_grid`]'s point-at-a-time loop gives
//! it: results are bit-identical to it.
//!
//! Written by hand: no crate offers a CPU hash-grid encoding (tiny-cuda-nn and its ports are
//! CUDA), and the loops must share their layout with the table and the sparse optimiser.

use crate::hash_level::{Level, HASH_PRIMES};
use nerf_core::truncate::truncate_u32;
use nerf_kernels::cpu_dispatch::dispatched;

/// Points per block.
pub(crate) const BLOCK: usize = 16;

/// The 8 corners' rows (within the level's table) and weights of a block's points, corner
/// `k` taking bit `a` of `k` on axis `a`, as [`Level::corners`] numbers them.
struct BlockCorners {
    rows: [[u32; BLOCK]; 8],
    weights: [[f32; BLOCK]; 8],
}

/// The corners of the first `points.len() / 3` (≤ [`BLOCK`]) points `(n, 3)` on `level`; the
/// lanes past them hold the corners of the origin (valid rows, never read).
#[inline(always)]
fn block_corners<const DENSE: bool>(level: &Level, points: &[f32]) -> BlockCorners {
    let n = points.len() / 3;
    let mut p = [[0f32; BLOCK]; 3];
    for (j, q) in points.chunks_exact(3).enumerate().take(BLOCK) {
        for a in 0..3 {
            p[a][j] = q[a];
        }
    }
    debug_assert!(n <= BLOCK);
    let res = level.resolution;
    let scale = res as f32;
    let multiplier = if DENSE {
        [1, res + 1, (res + 1) * (res + 1)]
    } else {
        HASH_PRIMES
    };
    // Per axis and lane: the two corner coordinates' terms of the row index and their weights.
    let mut terms = [[[0u32; BLOCK]; 2]; 3];
    let mut weights = [[[0f32; BLOCK]; 2]; 3];
    for a in 0..3 {
        for j in 0..BLOCK {
            // As in Level::corners: clamped, truncated (the floor for x ≥ 0; NaN casts to 0).
            let x = p[a][j].clamp(0.0, 1.0) * scale;
            let c = truncate_u32(x).min(res - 1);
            let frac = x - c as f32;
            weights[a][0][j] = 1.0 - frac;
            weights[a][1][j] = frac;
            terms[a][0][j] = c.wrapping_mul(multiplier[a]);
            terms[a][1][j] = (c + 1).wrapping_mul(multiplier[a]);
        }
    }
    let mut out = BlockCorners {
        rows: [[0; BLOCK]; 8],
        weights: [[0.0; BLOCK]; 8],
    };
    for k in 0..8 {
        let (x, y, z) = (k & 1, k >> 1 & 1, k >> 2 & 1);
        for j in 0..BLOCK {
            out.rows[k][j] = if DENSE {
                terms[0][x][j] + terms[1][y][j] + terms[2][z][j]
            } else {
                (terms[0][x][j] ^ terms[1][y][j] ^ terms[2][z][j]) & level.table_mask
            };
            // x, then y, then z, as Level::corners multiplies them.
            out.weights[k][j] = weights[0][x][j] * weights[1][y][j] * weights[2][z][j];
        }
    }
    out
}

/// Writes level `l`'s `f` features of each point of `points` `(m, 3)` into `out` `(m, width)`
/// at columns `l·f..(l+1)·f`, interpolated from `table`, that level's `(T, f)` rows.
#[inline(always)]
fn encode_level<const DENSE: bool>(
    level: &Level,
    table: &[f32],
    points: &[f32],
    out: &mut [f32],
    (width, l, f): (usize, usize, usize),
) {
    for (pts, out) in points.chunks(BLOCK * 3).zip(out.chunks_mut(BLOCK * width)) {
        let c = block_corners::<DENSE>(level, pts);
        for (j, o) in out.chunks_exact_mut(width).enumerate() {
            let o = &mut o[l * f..(l + 1) * f];
            // F = 2 (the usual choice) and 4: the sums in registers.
            if let Ok(o) = <&mut [f32; 2]>::try_from(&mut *o) {
                *o = blend_corners(&c, j, table);
            } else if let Ok(o) = <&mut [f32; 4]>::try_from(&mut *o) {
                *o = blend_corners(&c, j, table);
            } else {
                o.fill(0.0);
                for k in 0..8 {
                    let (row, w) = (c.rows[k][j] as usize * f, c.weights[k][j]);
                    for (o, v) in o.iter_mut().zip(&table[row..row + f]) {
                        *o += w * v;
                    }
                }
            }
        }
    }
}

/// Point `j`'s `F` features from the rows of `table` (`(T, F)`) at its 8 corners `c`,
/// weighted, summed in corner order from 0 (as the loop for any `F` sums them).
#[inline(always)]
fn blend_corners<const F: usize>(c: &BlockCorners, j: usize, table: &[f32]) -> [f32; F] {
    let mut sum = [0f32; F];
    for k in 0..8 {
        let (row, w) = (c.rows[k][j] as usize * F, c.weights[k][j]);
        let values: &[f32; F] = table[row..row + F].try_into().expect("F values");
        for (s, v) in sum.iter_mut().zip(values) {
            *s += w * v;
        }
    }
    sum
}

/// Adds level `l`'s share of the output gradient `grads` `(m, width)` of `points` `(m, 3)` into
/// `d`, that level's `(T, f)` table gradient, and sets the bit of every row written in
/// `touched` (one bit per row of the level).
#[inline(always)]
fn scatter_level<const DENSE: bool>(
    level: &Level,
    d: &mut [f32],
    touched: &mut [u64],
    points: &[f32],
    grads: &[f32],
    (width, l, f): (usize, usize, usize),
) {
    for (pts, grads) in points.chunks(BLOCK * 3).zip(grads.chunks(BLOCK * width)) {
        let c = block_corners::<DENSE>(level, pts);
        for (j, g) in grads.chunks_exact(width).enumerate() {
            let g = &g[l * f..(l + 1) * f];
            match f {
                2 => add_to_corners::<2>(&c, j, d, touched, g),
                4 => add_to_corners::<4>(&c, j, d, touched, g),
                _ => {
                    for k in 0..8 {
                        let (i, w) = (c.rows[k][j] as usize, c.weights[k][j]);
                        touched[i / 64] |= 1 << (i % 64);
                        for (d, g) in d[i * f..(i + 1) * f].iter_mut().zip(g) {
                            *d += w * g;
                        }
                    }
                }
            }
        }
    }
}

/// Adds point `j`'s output gradient `g` (its `F` values on this level), weighted, into the
/// rows of `d` (`(T, F)`) at its 8 corners `c` in corner order, and sets their bits in
/// `touched` (as the loop for any `F` does).
#[inline(always)]
fn add_to_corners<const F: usize>(
    c: &BlockCorners,
    j: usize,
    d: &mut [f32],
    touched: &mut [u64],
    g: &[f32],
) {
    let g: &[f32; F] = g.try_into().expect("F values");
    for k in 0..8 {
        let (i, w) = (c.rows[k][j] as usize, c.weights[k][j]);
        touched[i / 64] |= 1 << (i % 64);
        let row: &mut [f32; F] = (&mut d[i * F..(i + 1) * F]).try_into().expect("F values");
        for (d, g) in row.iter_mut().zip(g) {
            *d += w * g;
        }
    }
}

dispatched! {
    /// Encodes `points` `(m, 3)` on every level of `levels`: `out` `(m, L·f)`, level-major
    /// inside (all points on level 0, then level 1, ...), `table` the `(L·T, f)` rows.
    pub(crate) fn encode_points(
        levels: &[Level],
        table: &[f32],
        points: &[f32],
        out: &mut [f32],
        f: usize,
    ) = encode_points_portable for ["avx512f", "avx2"];
}

#[inline(always)]
fn encode_points_portable(
    levels: &[Level],
    table: &[f32],
    points: &[f32],
    out: &mut [f32],
    f: usize,
) {
    let (n_levels, width) = (levels.len(), levels.len() * f);
    let t = table.len() / (n_levels * f);
    for (l, level) in levels.iter().enumerate() {
        let table = &table[l * t * f..(l + 1) * t * f];
        if level.dense {
            encode_level::<true>(level, table, points, out, (width, l, f));
        } else {
            encode_level::<false>(level, table, points, out, (width, l, f));
        }
    }
}

dispatched! {
    /// The table gradient of level `l` (`level`) from the output gradient `grads` `(m, L·f)`
    /// of `points` `(m, 3)`: added into `d` (the level's `(T, f)` rows), each written row's bit
    /// set in `touched`.
    pub(crate) fn scatter_points(
        level: (&Level, usize),
        d: &mut [f32],
        touched: &mut [u64],
        points: &[f32],
        grads: &[f32],
        f: usize,
    ) = scatter_points_portable for ["avx512f", "avx2"];
}

#[inline(always)]
fn scatter_points_portable(
    (level, l): (&Level, usize),
    d: &mut [f32],
    touched: &mut [u64],
    points: &[f32],
    grads: &[f32],
    f: usize,
) {
    let width = grads.len() / (points.len() / 3).max(1);
    if level.dense {
        scatter_level::<true>(level, d, touched, points, grads, (width, l, f));
    } else {
        scatter_level::<false>(level, d, touched, points, grads, (width, l, f));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hash_level::HashGridParams;
    use nerf_kernels::test_support::uniform_values;

    /// The bit patterns (NaN equal to itself).
    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Levels both dense and hashed.
    fn levels(f: usize) -> (HashGridParams, Vec<Level>) {
        let p = HashGridParams {
            n_levels: 5,
            n_features: f,
            log2_table_size: 9,
            base_resolution: 2.0,
            max_resolution: 50.0,
        };
        let levels = p.levels();
        assert!(levels.iter().any(|l| l.dense) && levels.iter().any(|l| !l.dense));
        (p, levels)
    }

    /// `m` points in and around [0, 1]³ (clamped), with a NaN and the box's faces.
    fn points(m: usize) -> Vec<f32> {
        let mut pts = uniform_values(3 * m, 5, -0.2f32, 1.2);
        pts[..6].copy_from_slice(&[0.0, 1.0, 0.5, f32::NAN, 0.25, 1.0]);
        pts
    }

    #[test]
    fn blocks_encode_bit_for_bit_as_the_point_at_a_time_loop() {
        for f in [2, 3, 4] {
            let (p, levels) = levels(f);
            let t = p.table_size();
            let table = uniform_values(p.n_rows() * f, 7, -1.0f32, 1.0);
            // A multiple of the block and two remainders.
            for m in [BLOCK * 3, 37, 5] {
                let pts = points(m);
                let width = p.output_dim();
                let mut got = vec![0f32; m * width];
                encode_points(&levels, &table, &pts, &mut got, f);
                for (j, q) in pts.chunks(3).enumerate() {
                    for (l, level) in levels.iter().enumerate() {
                        let mut want = vec![0f32; f];
                        for (i, w) in level.corners([q[0], q[1], q[2]]) {
                            let row = (l * t + i as usize) * f;
                            for (o, v) in want.iter_mut().zip(&table[row..row + f]) {
                                *o += w * v;
                            }
                        }
                        let at = j * width + l * f;
                        assert_eq!(
                            bits(&got[at..at + f]),
                            bits(&want),
                            "F {f} m {m} point {j} level {l}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn blocks_scatter_bit_for_bit_as_the_point_at_a_time_loop() {
        for f in [2, 3, 4] {
            let (p, levels) = levels(f);
            let (t, width, m) = (p.table_size(), p.output_dim(), 41);
            let pts = points(m);
            let grads = uniform_values(m * width, 9, -1.0f32, 1.0);
            for (l, level) in levels.iter().enumerate() {
                let mut d = vec![0f32; t * f];
                let mut touched = vec![0u64; t.div_ceil(64)];
                scatter_points((level, l), &mut d, &mut touched, &pts, &grads, f);
                let mut want = vec![0f32; t * f];
                let mut want_touched = vec![false; t];
                for (q, g) in pts.chunks(3).zip(grads.chunks(width)) {
                    for (i, w) in level.corners([q[0], q[1], q[2]]) {
                        want_touched[i as usize] = true;
                        let row = i as usize * f;
                        for (d, g) in want[row..row + f].iter_mut().zip(&g[l * f..(l + 1) * f]) {
                            *d += w * g;
                        }
                    }
                }
                assert!(bits(&d) == bits(&want), "F {f} level {l}");
                for (r, &was) in want_touched.iter().enumerate() {
                    assert_eq!(
                        touched[r / 64] >> (r % 64) & 1 == 1,
                        was,
                        "level {l} row {r}"
                    );
                }
            }
        }
    }
}
