//! The volume-rendering maths, written once: sample spacing, optical depth, exclusive
//! transmittance, weights and their weighted sums, as tensor ops and as scalar functions for
//! the fused kernels.
//!
//! For samples `i = 1..S` along a ray with densities `σ_i` and spacings `Δ_i`
//! (`Δ_S = 1e10`, as in the homework):
//!
//! * transmittance `T_i = exp(−Σ_{j<i} σ_j Δ_j)` (so `T_1 = 1`; the cumulative product of
//!   `exp(−σ_j Δ_j)` written as one exclusive cumulative sum),
//! * weights `w_i = T_i · (1 − exp(−σ_i Δ_i))`,
//! * colour `Σ w_i c_i`, depth `Σ w_i t_i`, opacity `Σ w_i`.
//!
//! Stable limits: optical depths `σΔ` are clamped to [`MAX_OPTICAL_DEPTH`] before the sum.
//! `exp(−x)` is exactly 0 in f32 for any x above about 104, so the clamp changes no weight, but
//! it turns `σ = ∞` (the homework's `−ln(1 − density)` at density 1) into a finite number and
//! keeps the tensor cumulative sum free of `∞ · 0 = NaN`. Samples with zero spacing (`near =
//! far`, or coincident jittered depths) have zero optical depth whatever their σ: the limit of
//! a bounded density over a vanishing interval, where the homework's SDF formula
//! `σ = −ln(1 − density)/Δ` would give `∞ · 0`. The same code path serves rendering
//! and training (everything is differentiable Candle ops).

use anyhow::Result;
use candle_core::{Tensor, D};

/// Spacing used for the last sample of every ray, as in the homework.
pub(crate) const LAST_DELTA: f64 = 1e10;

/// Optical depths are clamped to this value (see the module documentation).
pub const MAX_OPTICAL_DEPTH: f64 = 1e4;

/// Distances between consecutive samples, `1e10` for the last one.
///
/// `lengths`: `(N, S, 1)`; returns `(N, S, 1)`.
pub fn deltas(lengths: &Tensor) -> Result<Tensor> {
    let (n, s, _) = lengths.dims3()?;
    let last =
        Tensor::full(LAST_DELTA as f32, (n, 1, 1), lengths.device())?.to_dtype(lengths.dtype())?;
    if s == 1 {
        return Ok(last);
    }
    let diff = lengths
        .narrow(1, 1, s - 1)?
        .sub(&lengths.narrow(1, 0, s - 1)?)?;
    Ok(Tensor::cat(&[&diff, &last], 1)?)
}

/// Exclusive cumulative sum along dimension 1: `out[:, i] = Σ_{j<i} x[:, j]`.
///
/// `x`: `(N, S)`; returns `(N, S)`. Written as a product with a strictly upper-triangular
/// matrix so that it is one differentiable matmul.
pub fn exclusive_cumsum(x: &Tensor) -> Result<Tensor> {
    let (_, s) = x.dims2()?;
    let mask: Vec<f32> = (0..s * s)
        .map(|k| if k / s < k % s { 1.0 } else { 0.0 })
        .collect();
    let mask = Tensor::from_vec(mask, (s, s), x.device())?.to_dtype(x.dtype())?;
    Ok(x.matmul(&mask)?)
}

/// Clamped optical depth `σ·Δ` of each sample (0 where `Δ = 0`).
///
/// `density`, `deltas`: `(N, S, 1)`; returns `(N, S, 1)`.
pub(crate) fn optical_depth(density: &Tensor, deltas: &Tensor) -> Result<Tensor> {
    let tau = density.mul(deltas)?.clamp(0f32, MAX_OPTICAL_DEPTH as f32)?;
    // Zero spacing: zero optical depth, even where σ is ∞ or NaN (σ = −ln(1 − d)/0).
    let zero_spacing = deltas.eq(0f64)?;
    Ok(zero_spacing.where_cond(&tau.zeros_like()?, &tau)?)
}

/// Exclusive transmittance `T_i = exp(−Σ_{j<i} τ_j)` from optical depths `τ`.
///
/// `optical_depth`: `(N, S, 1)`; returns `(N, S, 1)` with `T_1 = 1`.
pub(crate) fn transmittance(optical_depth: &Tensor) -> Result<Tensor> {
    let tau = optical_depth.squeeze(D::Minus1)?;
    Ok(exclusive_cumsum(&tau)?.neg()?.exp()?.unsqueeze(D::Minus1)?)
}

/// Rendering weights `w_i = T_i (1 − exp(−σ_i Δ_i))`.
///
/// `density`, `deltas`: `(N, S, 1)`; returns `(N, S, 1)`, each in [0, 1] with `Σ w ≤ 1`.
pub fn weights(density: &Tensor, deltas: &Tensor) -> Result<Tensor> {
    let tau = optical_depth(density, deltas)?;
    let alpha = tau.neg()?.exp()?.affine(-1.0, 1.0)?;
    Ok(transmittance(&tau)?.mul(&alpha)?)
}

/// Weighted sum over samples.
///
/// `weights`: `(N, S, 1)`, `values`: `(N, S, C)`; returns `(N, C)`.
pub fn aggregate(weights: &Tensor, values: &Tensor) -> Result<Tensor> {
    Ok(values.broadcast_mul(weights)?.sum(1)?)
}

/// Optical depth of one sample, clamped as in `optical_depth`: `σΔ` in
/// `[0, MAX_OPTICAL_DEPTH]`, and 0 for zero spacing whatever σ is (the homework's SDF σ is
/// `−ln(1 − density)/Δ`, which is ∞ or NaN at Δ = 0).
#[inline]
pub fn clamped_optical_depth(sigma: f32, delta: f32) -> f32 {
    if delta == 0.0 {
        0.0
    } else {
        (sigma * delta).clamp(0.0, MAX_OPTICAL_DEPTH as f32)
    }
}

/// Weights of one ray: `tau` (S) → `weights` (S) and `transmittance_after` (S), where
/// `transmittance_after[i] = T_{i+1}`. Transmittance is the running product of `e^{−τ}`, as
/// the homework's cumprod.
#[inline]
pub fn ray_weights(tau: &[f32], weights: &mut [f32], transmittance_after: &mut [f32]) {
    let mut t = 1f32;
    for i in 0..tau.len() {
        let a = (-tau[i]).exp();
        weights[i] = t * (1.0 - a);
        t *= a;
        transmittance_after[i] = t;
    }
}

/// Spacing after sample `i` of one ray whose sample lengths are `lengths` (S):
/// `t_{i+1} − t_i`, and `LAST_DELTA` for the last sample — the scalar form of [`deltas`].
#[inline]
pub fn spacing(lengths: &[f32], i: usize) -> f32 {
    if i + 1 < lengths.len() {
        lengths[i + 1] - lengths[i]
    } else {
        LAST_DELTA as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    fn t3(v: &[f32], n: usize, s: usize) -> Tensor {
        Tensor::from_vec(v.to_vec(), (n, s, 1), &Device::Cpu).unwrap()
    }

    #[test]
    fn deltas_end_with_1e10() {
        let l = t3(&[1.0, 1.5, 3.0, 0.0, 2.0, 2.5], 2, 3);
        let d = deltas(&l)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert_eq!(d, vec![0.5, 1.5, 1e10, 2.0, 0.5, 1e10]);
        let one = deltas(&t3(&[2.0], 1, 1))
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert_eq!(one, vec![1e10]);
    }

    #[test]
    fn exclusive_cumsum_by_hand() {
        let x = Tensor::new(&[[1f32, 2., 3., 4.], [0., -1., 5., 0.5]], &Device::Cpu).unwrap();
        let c = exclusive_cumsum(&x).unwrap().to_vec2::<f32>().unwrap();
        assert_eq!(c, vec![vec![0., 1., 3., 6.], vec![0., 0., -1., 4.]]);
    }

    /// Weights recomputed in f64 with the cumulative product, as the homework writes it.
    fn reference_weights(sigma: &[f64], delta: &[f64]) -> Vec<f64> {
        let mut t = 1.0;
        sigma
            .iter()
            .zip(delta)
            .map(|(s, d)| {
                let a = (-s * d).exp();
                let w = t * (1.0 - a);
                t *= a;
                w
            })
            .collect()
    }

    #[test]
    fn weights_match_float64_cumprod() {
        let sigma = [0.0f32, 0.3, 2.0, 0.1, 7.5, 0.0, 1.0, 3.0];
        let lengths = [0.0f32, 0.4, 0.9, 1.0, 1.7, 2.2, 3.0, 3.1];
        let l = t3(&lengths, 1, 8);
        let d = deltas(&l).unwrap();
        let w = weights(&t3(&sigma, 1, 8), &d)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let dv: Vec<f64> = d
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap()
            .iter()
            .map(|&v| v as f64)
            .collect();
        let sv: Vec<f64> = sigma.iter().map(|&v| v as f64).collect();
        let r = reference_weights(&sv, &dv);
        for (a, b) in w.iter().zip(&r) {
            assert!((*a as f64 - b).abs() < 1e-6, "{a} vs {b}");
        }
        // The last delta is 1e10, so a ray with any density at its end is fully absorbed.
        let total: f32 = w.iter().sum();
        assert!((total - 1.0).abs() < 1e-6);
    }

    #[test]
    fn weights_are_bounded_even_for_infinite_density() {
        let sigma = [0.0f32, f32::INFINITY, 1e10, 0.0];
        let l = t3(&[1.0, 2.0, 3.0, 4.0], 1, 4);
        let w = weights(&t3(&sigma, 1, 4), &deltas(&l).unwrap()).unwrap();
        let w = w.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert_eq!(w, vec![0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn aggregate_shapes() {
        let w = Tensor::ones((5, 7, 1), DType::F32, &Device::Cpu).unwrap();
        let v = Tensor::ones((5, 7, 3), DType::F32, &Device::Cpu).unwrap();
        let a = aggregate(&w, &v).unwrap();
        assert_eq!(a.dims(), &[5, 3]);
        assert_eq!(a.to_vec2::<f32>().unwrap()[0], vec![7.0, 7.0, 7.0]);
    }
}
