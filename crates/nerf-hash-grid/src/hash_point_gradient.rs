//! The hash encoding's gradient with respect to its input points
//! ([`crate::hash_grid`]), for training that moves the points (camera refinement:
//! the points are `o + t·d` of rays whose cameras are optimised).
//!
//! On level `l` a point's features are `Σ_k w_k(x) · T[row_k]` with `x = clamp(p, 0, 1)·N_l`
//! and `w_k = Π_a w_a` the trilinear weights; so `∂feature/∂p_a = Σ_k ∂w_k/∂p_a · T[row_k]`
//! with `∂w_k/∂p_a = ±N_l·Π_{b≠a} w_b` ([`Level::corner_gradients`]), 0 on an axis where the
//! point is clamped. The table rows themselves do not depend on the point (the gradient is
//! that of the piecewise-trilinear interpolant inside each cell).
//!
//! Both forms run only when the points are tracked by autograd: ordinary training and
//! rendering (points from the host, never tracked) pay nothing.
//!
//! * Fused: [`point_gradients`] walks blocks of points in parallel, one level at a time, and
//!   sums `∂w_k/∂p · ⟨grad_l, T[row_k]⟩` over the 8 corners.
//! * Twin: [`tracked_corner_weights`] builds the trilinear weights as tensor ops on the
//!   points, so that Candle's autograd differentiates them (their values are exactly the
//!   host weights of [`crate::hash_grid::hash_encode_generic`]).

use candle_core::{DType, Tensor};
use rayon::prelude::*;

use crate::hash_level::{HashGridParams, Level};

/// Points per task of [`point_gradients`] (a task walks them one level at a time).
const POINTS_PER_TASK: usize = 1024;

/// The gradient `(m, 3)` of a loss with respect to `points` `(m, 3)` given its gradient
/// `grads` `(m, L·f)` with respect to their encoding by `table` (the `(L·T, f)` rows, level
/// `l` at rows `l·T..(l+1)·T`) on `levels`.
pub(crate) fn point_gradients(
    levels: &[Level],
    table: &[f32],
    points: &[f32],
    grads: &[f32],
    f: usize,
) -> Vec<f32> {
    let width = levels.len() * f;
    let t = table.len() / (levels.len() * f).max(1);
    let mut out = vec![0f32; points.len()];
    out.par_chunks_mut(POINTS_PER_TASK * 3)
        .zip(points.par_chunks(POINTS_PER_TASK * 3))
        .zip(grads.par_chunks(POINTS_PER_TASK * width))
        .for_each(|((out, points), grads)| {
            // Level by level, so that the reads stay in one level's slice of the table (as
            // the fused forward pass walks it).
            for (l, level) in levels.iter().enumerate() {
                let table = &table[l * t * f..(l + 1) * t * f];
                for ((d, q), g) in out
                    .chunks_exact_mut(3)
                    .zip(points.chunks_exact(3))
                    .zip(grads.chunks_exact(width))
                {
                    let g = &g[l * f..(l + 1) * f];
                    for (row, _, dw) in level.corner_gradients([q[0], q[1], q[2]]) {
                        let at = row as usize * f;
                        let s: f32 = g.iter().zip(&table[at..at + f]).map(|(g, v)| g * v).sum();
                        for a in 0..3 {
                            d[a] += s * dw[a];
                        }
                    }
                }
            }
        });
    out
}

/// The trilinear weights `(M·L·8, 1)` of every point's corners (point-major, then level, then
/// corner, as [`crate::hash_grid`]'s corner rows), as tensor ops on `points` `(M, 3)`
/// so that autograd carries their gradient to the points. `host` holds the points' f32
/// values. The values equal the host weights bit for bit: each axis' fraction is the host's
/// plus `(p − p̄)·∂fraction/∂p`, where `p̄` is `p` detached (a zero that carries the slope).
pub(crate) fn tracked_corner_weights(
    points: &Tensor,
    host: &[f32],
    params: &HashGridParams,
) -> candle_core::Result<Tensor> {
    let levels = params.levels();
    let (m, l) = (host.len() / 3, levels.len());
    let mut fractions = Vec::with_capacity(m * l * 3);
    let mut slopes = Vec::with_capacity(m * l * 3);
    for q in host.chunks_exact(3) {
        for level in &levels {
            for &v in q {
                fractions.push(level.cell(v).1);
                slopes.push(level.cell_slope(v));
            }
        }
    }
    let dev = points.device();
    let fractions = Tensor::from_vec(fractions, (m, l, 3), dev)?;
    let slopes = Tensor::from_vec(slopes, (m, l, 3), dev)?;
    let shift = points
        .sub(&points.detach())?
        .to_dtype(DType::F32)?
        .unsqueeze(1)?;
    let upper = fractions.add(&shift.broadcast_mul(&slopes)?)?;
    let lower = upper.affine(-1.0, 1.0)?;
    // (M, L, 6): per axis its lower-side then upper-side weight.
    let per_axis = Tensor::stack(&[&lower, &upper], 3)?.reshape((m, l, 6))?;
    let pick: Vec<u32> = (0..8u32)
        .flat_map(|k| (0..3u32).map(move |a| 2 * a + (k >> a & 1)))
        .collect();
    let pick = Tensor::from_vec(pick, 24, dev)?;
    let w = per_axis.index_select(&pick, 2)?.reshape((m, l, 8, 3))?;
    // x, then y, then z, as Level::corners multiplies them.
    let w = w
        .narrow(3, 0, 1)?
        .mul(&w.narrow(3, 1, 1)?)?
        .mul(&w.narrow(3, 2, 1)?)?;
    w.reshape((m * l * 8, 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding_f64::hash_encoding_f64;
    use crate::hash_grid::{hash_encode, hash_encode_generic};
    use candle_core::{Device, Var};
    use nerf_kernels::test_support::uniform_values;
    use nerf_kernels::{with_kernel_choice, KernelChoice};

    fn params() -> HashGridParams {
        HashGridParams {
            n_levels: 4,
            n_features: 2,
            log2_table_size: 8,
            base_resolution: 2.0,
            max_resolution: 40.0,
        }
    }

    /// Points at least 1e-3 of a cell from every cell face of every level (so that a small
    /// step stays in its cell), some outside the box on an axis (clamped: no gradient there).
    fn points(p: &HashGridParams, m: usize) -> Vec<f32> {
        let levels = p.levels();
        let near_a_face = |v: f32| {
            levels.iter().any(|lv| {
                let x = v as f64 * lv.resolution as f64;
                (x - x.round()).abs() < 1e-3
            })
        };
        uniform_values(3 * m, 11, -0.1, 1.1)
            .into_iter()
            .map(|v| {
                let mut v = v as f32;
                while near_a_face(v) {
                    v += 2.7e-4;
                }
                v
            })
            .collect()
    }

    fn table(p: &HashGridParams) -> Var {
        let v: Vec<f32> = uniform_values(p.n_rows() * p.n_features, 5, -1.0, 1.0)
            .into_iter()
            .map(|v| v as f32)
            .collect();
        Var::from_tensor(&Tensor::from_vec(v, (p.n_rows(), p.n_features), &Device::Cpu).unwrap())
            .unwrap()
    }

    /// `Σ proj ⊙ encode(points)`'s gradient with respect to `points`, by `choice`.
    fn point_gradient(choice: KernelChoice, pts: &[f32], table: &Var, proj: &Tensor) -> Vec<f32> {
        let p = params();
        let m = pts.len() / 3;
        let points =
            Var::from_tensor(&Tensor::from_vec(pts.to_vec(), (m, 3), &Device::Cpu).unwrap())
                .unwrap();
        with_kernel_choice(choice, || {
            let enc = hash_encode(points.as_tensor(), table, &p, None).unwrap();
            let grads = (enc * proj).unwrap().sum_all().unwrap().backward().unwrap();
            let g = grads.get(points.as_tensor()).expect("a point gradient");
            g.flatten_all().unwrap().to_vec1::<f32>().unwrap()
        })
    }

    #[test]
    fn point_gradient_matches_finite_differences_of_a_float64_encoding() {
        let p = params();
        let m = 60;
        let pts = points(&p, m);
        let table = table(&p);
        let host_table: Vec<f32> = table.flatten_all().unwrap().to_vec1().unwrap();
        let proj: Vec<f64> = uniform_values(m * p.output_dim(), 3, -1.0, 1.0);
        let proj_t = Tensor::from_vec(
            proj.iter().map(|&v| v as f32).collect::<Vec<_>>(),
            (m, p.output_dim()),
            &Device::Cpu,
        )
        .unwrap();
        for choice in [KernelChoice::Fused, KernelChoice::Generic] {
            let g = point_gradient(choice, &pts, &table, &proj_t);
            let mut clamped = 0;
            for j in 0..m {
                let row = &proj[j * p.output_dim()..(j + 1) * p.output_dim()];
                let loss = |q: [f64; 3]| -> f64 {
                    hash_encoding_f64(q, &host_table, &p)
                        .iter()
                        .zip(row)
                        .map(|(e, w)| e * w)
                        .sum()
                };
                for a in 0..3 {
                    let q: [f64; 3] = std::array::from_fn(|b| pts[3 * j + b] as f64);
                    let eps = 1e-5;
                    let (mut hi, mut lo) = (q, q);
                    hi[a] += eps;
                    lo[a] -= eps;
                    let fd = (loss(hi) - loss(lo)) / (2.0 * eps);
                    let got = g[3 * j + a] as f64;
                    if !(0.0..=1.0).contains(&q[a]) {
                        assert_eq!(got, 0.0, "{choice:?} point {j} axis {a}: clamped");
                        clamped += 1;
                    }
                    assert!(
                        (got - fd).abs() < 1e-3 * (1.0 + fd.abs()),
                        "{choice:?} point {j} axis {a}: analytic {got}, finite difference {fd}"
                    );
                }
            }
            assert!(clamped > 0, "no point outside the box was tested");
        }
    }

    #[test]
    fn fused_and_twin_point_gradients_agree_and_the_twin_forward_is_unchanged() {
        let p = params();
        let m = 700;
        let pts: Vec<f32> = uniform_values(3 * m, 21, -0.05, 1.05)
            .into_iter()
            .map(|v| v as f32)
            .collect();
        let table = table(&p);
        let proj: Vec<f32> = uniform_values(m * p.output_dim(), 4, -1.0, 1.0)
            .into_iter()
            .map(|v| v as f32)
            .collect();
        let proj = Tensor::from_vec(proj, (m, p.output_dim()), &Device::Cpu).unwrap();
        let fused = point_gradient(KernelChoice::Fused, &pts, &table, &proj);
        let twin = point_gradient(KernelChoice::Generic, &pts, &table, &proj);
        let scale = fused.iter().fold(0f32, |a, v| a.max(v.abs()));
        let diff = fused
            .iter()
            .zip(&twin)
            .fold(0f32, |a, (x, y)| a.max((x - y).abs()));
        assert!(scale > 1.0 && diff < 1e-5 * scale, "{diff} of {scale}");
        // The twin's values with tracked points are the untracked twin's, bit for bit.
        let plain = Tensor::from_vec(pts.clone(), (m, 3), &Device::Cpu).unwrap();
        let tracked = Var::from_tensor(&plain).unwrap();
        let a = hash_encode_generic(&plain, &table, &p).unwrap();
        let b = hash_encode_generic(tracked.as_tensor(), &table, &p).unwrap();
        let bits = |t: &Tensor| -> Vec<u32> {
            let v: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
            v.iter().map(|x| x.to_bits()).collect()
        };
        assert_eq!(bits(&a), bits(&b));
    }

    #[test]
    fn untracked_points_get_no_gradient() {
        let p = params();
        let table = table(&p);
        let points = Tensor::from_vec(vec![0.3f32, 0.6, 0.2], (1, 3), &Device::Cpu).unwrap();
        for choice in [KernelChoice::Fused, KernelChoice::Generic] {
            let grads = with_kernel_choice(choice, || {
                let enc = hash_encode(&points, &table, &p, None).unwrap();
                enc.sum_all().unwrap().backward().unwrap()
            });
            assert!(grads.get(&points).is_none(), "{choice:?}");
            assert!(grads.get(&table).is_some(), "{choice:?}");
        }
    }
}
