//! The distortion loss of N rays (the per-ray maths of `ray_distortion`) as a fused CPU kernel,
//! forward and backward with respect to the densities, on dense samples and on the packed
//! samples of a skipping render, with their tensor-op twins.
//!
//! Per ray: optical depths `τ_i = clamp(σ_i Δ_i)` and weights `w_i` as compositing makes them
//! ([`nerf_core::volume`]), each sample's interval `[s(t_i), s(t_i + Δ_i)]` of the
//! normalised distance ([`RaySpacing`]), then `L` and `∂L/∂w` in O(n)
//! (`ray_distortion` and `ray_distortion_gradient` of `ray_distortion.rs`), and `∂L/∂σ_i = Δ_i ∂L/∂τ_i` through the
//! weights (`weight_gradient_to_optical_depth`; 0 where the optical depth is clamped).
//! Lengths get no gradient. A packed render's skipped samples have σ = 0: weight 0, and no
//! change to the transmittance, so they are left out (the twin scatters zeros there).

use anyhow::Result;
use candle_core::{DType, Shape, Tensor, D};
use rayon::prelude::*;

use crate::composite::{lengths_per_ray, scatter_rows, PackedDensities, PackedRays};
use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
pub use crate::ray_distortion::RaySpacing;
use crate::ray_distortion::{
    ray_distortion, ray_distortion_gradient, weight_gradient_to_optical_depth,
};
use crate::storage::host_values;
use crate::use_fused;
use nerf_core::volume::{
    clamped_optical_depth, deltas, exclusive_cumsum, ray_weights, spacing, weights,
    MAX_OPTICAL_DEPTH,
};

/// One ray's loss from its listed samples' densities σ, depths t and spacings Δ (k each); with
/// `grad = (G, out)`, `G · ∂L/∂σ` into `out` (k).
fn ray_loss(
    sigma: &[f32],
    t: &[f32],
    delta: &[f32],
    spacing: RaySpacing,
    grad: Option<(f32, &mut [f32])>,
) -> f32 {
    let k = sigma.len();
    let tau: Vec<f32> = (0..k)
        .map(|i| clamped_optical_depth(sigma[i], delta[i]))
        .collect();
    let (mut w, mut t_after) = (vec![0f32; k], vec![0f32; k]);
    ray_weights(&tau, &mut w, &mut t_after);
    let (start, end): (Vec<f32>, Vec<f32>) =
        (0..k).map(|i| spacing.interval(t[i], delta[i])).unzip();
    let loss = ray_distortion(&w, &start, &end);
    if let Some((upstream, out)) = grad {
        let mut g = vec![0f32; k];
        ray_distortion_gradient(&w, &start, &end, &mut g);
        g.iter_mut().for_each(|v| *v *= upstream);
        weight_gradient_to_optical_depth(&w, &t_after, &mut g);
        for i in 0..k {
            let raw = sigma[i] * delta[i];
            let active = (0.0..MAX_OPTICAL_DEPTH as f32).contains(&raw);
            out[i] = if active { delta[i] * g[i] } else { 0.0 };
        }
    }
    loss
}

/// Each ray's distortion loss `(N, 1)` from densities and lengths `(N, S, 1)`, measured in
/// `spacing`. Differentiable in `density`. The fused kernel where [`use_fused`] allows, else
/// [`distortion_loss_tensor_ops`].
pub fn distortion_loss(density: &Tensor, lengths: &Tensor, spacing: RaySpacing) -> Result<Tensor> {
    if !use_fused(density) {
        return distortion_loss_tensor_ops(density, lengths, spacing);
    }
    let (density, lengths) = (density.contiguous()?, lengths.contiguous()?);
    let op = Fused(DenseDistortion { spacing });
    Ok(if density.track_op() {
        density.apply_op2(&lengths, op)?
    } else {
        density.apply_op2_no_bwd(&lengths, &op)?
    })
}

/// [`distortion_loss`] as Candle tensor ops (any device and dtype; differentiable): the
/// weights of [`nerf_core::volume::weights`], the intervals from the lengths (no gradient),
/// and the prefix-sum form with [`exclusive_cumsum`].
///
/// `density`, `lengths`: `(N, S, 1)`; returns `(N, 1)`.
pub fn distortion_loss_tensor_ops(
    density: &Tensor,
    lengths: &Tensor,
    spacing: RaySpacing,
) -> Result<Tensor> {
    let (n, s, _) = density.dims3()?;
    let deltas = deltas(lengths)?;
    let w = weights(density, &deltas)?.squeeze(D::Minus1)?;
    let flat = |t: &Tensor| -> Result<Vec<f32>> {
        Ok(t.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?)
    };
    let (t, d) = (flat(lengths)?, flat(&deltas)?);
    let (start, end): (Vec<f32>, Vec<f32>) = t
        .iter()
        .zip(&d)
        .map(|(&t, &d)| spacing.interval(t, d))
        .unzip();
    let as_tensor = |v: Vec<f32>| -> Result<Tensor> {
        Ok(Tensor::from_vec(v, (n, s), density.device())?.to_dtype(density.dtype())?)
    };
    let (start, end) = (as_tensor(start)?, as_tensor(end)?);
    let mid = ((&start + &end)? * 0.5)?;
    let width = (&end - &start)?;
    let w_before = exclusive_cumsum(&w)?;
    let x_before = exclusive_cumsum(&(&w * &mid)?)?;
    let between = (&w * ((&mid * &w_before)? - x_before)?)?
        .sum_keepdim(1)?
        .affine(2.0, 0.0)?;
    let within = (w.sqr()? * width)?.sum_keepdim(1)?.affine(1.0 / 3.0, 0.0)?;
    Ok((between + within)?)
}

struct DenseDistortion {
    spacing: RaySpacing,
}

impl DenseDistortion {
    /// Ray `ray`'s lengths (S) and spacings (S) from all rays' lengths.
    fn ray(lengths: &[f32], s: usize, ray: usize) -> (&[f32], Vec<f32>) {
        let t = &lengths[ray * s..(ray + 1) * s];
        (t, (0..s).map(|i| spacing(t, i)).collect())
    }
}

impl CpuKernel<2> for DenseDistortion {
    const NAME: &'static str = "distortion-loss";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [density, lengths] = CpuInput::all_f32(&inputs, "distortion loss")?;
        let (n, s, _) = inputs[0].shape().dims3()?;
        if inputs[1].shape().dims3()? != (n, s, 1) {
            candle_core::bail!("distortion loss: densities and lengths disagree in shape");
        }
        let out: Vec<f32> = (0..n)
            .into_par_iter()
            .map(|ray| {
                let (t, delta) = Self::ray(lengths, s, ray);
                let sigma = &density[ray * s..(ray + 1) * s];
                ray_loss(sigma, t, &delta, self.spacing, None)
            })
            .collect();
        Ok((out, Shape::from((n, 1))))
    }

    fn gradients(&self, [density, lengths]: [&Tensor; 2], grad: &Tensor) -> KernelGradients<2> {
        let (n, s, _) = density.dims3()?;
        let [sigma, lens, upstream] = host_values([density, lengths, grad])?;
        let mut g_sigma = vec![0f32; n * s];
        g_sigma
            .par_chunks_mut(s.max(1))
            .enumerate()
            .for_each(|(ray, out)| {
                let (t, delta) = Self::ray(&lens, s, ray);
                let sigma = &sigma[ray * s..(ray + 1) * s];
                ray_loss(sigma, t, &delta, self.spacing, Some((upstream[ray], out)));
            });
        Ok([
            Some(Tensor::from_vec(
                g_sigma,
                density.shape(),
                density.device(),
            )?),
            None,
        ])
    }
}

/// Each ray's distortion loss `(N, 1)` from the packed densities of a skipping render
/// (`samples.density` `(M, 1)` at the flat sample indices `samples.index`, no repeats) over
/// rays whose lengths are `lengths` `(N, S, 1)` (or `(1, S, 1)` shared). Samples not listed
/// have σ = 0. Differentiable in the densities; only the listed samples are visited. The fused
/// kernel where [`use_fused`] allows, else its twin `distortion_loss_packed_tensor_ops`.
pub fn distortion_loss_packed(
    samples: PackedDensities,
    lengths: &Tensor,
    spacing: RaySpacing,
) -> Result<Tensor> {
    if !use_fused(&samples.density) {
        return distortion_loss_packed_tensor_ops(samples, lengths, spacing);
    }
    let PackedDensities {
        index,
        n_rays,
        density,
    } = samples;
    let rays = PackedRays::with_lengths(index, n_rays, lengths, "distortion loss")?;
    let density = density.contiguous()?;
    let op = Fused(PackedDistortion { rays, spacing });
    Ok(if density.track_op() {
        density.apply_op1(op)?
    } else {
        density.apply_op1_no_bwd(&op)?
    })
}

/// The twin of [`distortion_loss_packed`] (any device and dtype): the densities scattered into
/// a dense `(N, S, 1)` tensor, zeros at the samples not listed (`index_add`,
/// differentiable), then [`distortion_loss_tensor_ops`].
pub(crate) fn distortion_loss_packed_tensor_ops(
    samples: PackedDensities,
    lengths: &Tensor,
    spacing: RaySpacing,
) -> Result<Tensor> {
    let (n, s) = (samples.n_rays, lengths.dim(1)?);
    let m = samples.index.len();
    let index = Tensor::from_vec(samples.index, m, samples.density.device())?;
    let dense = scatter_rows(&index, (n, s), &samples.density)?;
    let lengths = lengths_per_ray(lengths, n, dense.dtype())?;
    distortion_loss_tensor_ops(&dense, &lengths, spacing)
}

struct PackedDistortion {
    rays: PackedRays,
    spacing: RaySpacing,
}

impl PackedDistortion {
    /// Ray `ray`'s listed samples in order: entries, densities, depths and spacings.
    #[allow(clippy::type_complexity)]
    fn ray(&self, ray: usize, density: &[f32]) -> (Vec<usize>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let t_ray = self.rays.ray_lengths(ray);
        let mut out = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (e, i, delta, _) in self.rays.walk(ray, density) {
            out.0.push(e);
            out.1.push(density[e]);
            out.2.push(t_ray[i]);
            out.3.push(delta);
        }
        out
    }
}

impl CpuKernel<1> for PackedDistortion {
    const NAME: &'static str = "packed-distortion-loss";

    fn cpu_forward(&self, [input]: [CpuInput; 1]) -> KernelOutput {
        let density = input.f32("packed distortion loss")?;
        let m = self.rays.index.len();
        if density.len() != m {
            candle_core::bail!(
                "packed distortion loss: {} densities for {m} samples",
                density.len()
            );
        }
        let out: Vec<f32> = (0..self.rays.n)
            .into_par_iter()
            .map(|ray| {
                let (_, sigma, t, delta) = self.ray(ray, density);
                ray_loss(&sigma, &t, &delta, self.spacing, None)
            })
            .collect();
        Ok((out, Shape::from((self.rays.n, 1))))
    }

    fn gradients(&self, [density]: [&Tensor; 1], grad: &Tensor) -> KernelGradients<1> {
        let [sigma_all, upstream] = host_values([density, grad])?;
        let per_ray: Vec<(Vec<usize>, Vec<f32>)> = (0..self.rays.n)
            .into_par_iter()
            .map(|ray| {
                let (entries, sigma, t, delta) = self.ray(ray, &sigma_all);
                let mut g = vec![0f32; entries.len()];
                ray_loss(
                    &sigma,
                    &t,
                    &delta,
                    self.spacing,
                    Some((upstream[ray], &mut g)),
                );
                (entries, g)
            })
            .collect();
        let mut g_sigma = vec![0f32; sigma_all.len()];
        for (entries, g) in per_ray {
            for (e, v) in entries.into_iter().zip(g) {
                g_sigma[e] = v;
            }
        }
        Ok([Some(Tensor::from_vec(
            g_sigma,
            density.shape(),
            density.device(),
        )?)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{with_kernel_choice, KernelChoice};
    use candle_core::{Device, Var};
    use nerf_core::compare::max_abs_difference;

    const SPACING: RaySpacing = RaySpacing::LinearThenDisparity {
        near: 0.5,
        switch: 2.0,
        far: 50.0,
        linear_share: 0.75,
    };

    /// Densities (positive, some tiny) and increasing lengths `(N, S, 1)` from 0.5, crossing
    /// the switch at 2.
    fn inputs(n: usize, s: usize, seed: u64) -> (Tensor, Tensor) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let sigma: Vec<f32> = (0..n * s)
            .map(|_| match rng.random::<f32>() {
                u if u < 0.3 => 1e-3,
                u => u * 3.0,
            })
            .collect();
        let mut lengths = Vec::new();
        for _ in 0..n {
            let mut t = 0.5f32;
            for _ in 0..s {
                lengths.push(t);
                t += rng.random::<f32>() * 0.4;
            }
        }
        let dev = &Device::Cpu;
        (
            Tensor::from_vec(sigma, (n, s, 1), dev).unwrap(),
            Tensor::from_vec(lengths, (n, s, 1), dev).unwrap(),
        )
    }

    /// The loss of every ray recomputed in f64 by the O(n²) definition, with weights by the
    /// cumulative product.
    fn reference(sigma: &[f32], lengths: &[f32], s: usize) -> Vec<f64> {
        sigma
            .chunks(s)
            .zip(lengths.chunks(s))
            .map(|(sig, t)| {
                let mut trans = 1f64;
                let mut rows = Vec::new();
                for i in 0..s {
                    let delta = if i + 1 < s {
                        f64::from(t[i + 1]) - f64::from(t[i])
                    } else {
                        1e10
                    };
                    let a = (-(f64::from(sig[i]) * delta).min(1e4)).exp();
                    let w = trans * (1.0 - a);
                    trans *= a;
                    let t0 = f64::from(t[i]);
                    let (sa, sb) = (SPACING.normalised(t0), SPACING.normalised(t0 + delta));
                    rows.push((w, 0.5 * (sa + sb), sb - sa));
                }
                let mut l = 0.0;
                for &(wi, mi, di) in &rows {
                    for &(wj, mj, _) in &rows {
                        l += wi * wj * (mi - mj).abs();
                    }
                    l += wi * wi * di / 3.0;
                }
                l
            })
            .collect()
    }

    #[test]
    fn fused_and_twin_match_the_quadratic_definition_in_f64() {
        let (n, s) = (50, 24);
        let (sigma, lengths) = inputs(n, s, 1);
        let want = reference(
            &sigma.flatten_all().unwrap().to_vec1().unwrap(),
            &lengths.flatten_all().unwrap().to_vec1().unwrap(),
            s,
        );
        let fused = distortion_loss(&sigma, &lengths, SPACING).unwrap();
        let twin = distortion_loss_tensor_ops(&sigma, &lengths, SPACING).unwrap();
        let twin64 = distortion_loss_tensor_ops(
            &sigma.to_dtype(DType::F64).unwrap(),
            &lengths.to_dtype(DType::F64).unwrap(),
            SPACING,
        )
        .unwrap();
        assert_eq!(fused.dims(), &[n, 1]);
        for (name, got, tol) in [("fused", &fused, 1e-5), ("twin", &twin, 1e-4)] {
            let got = got.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    (f64::from(*g) - w).abs() < tol * w.max(1e-2),
                    "{name}: {g} vs {w}"
                );
            }
        }
        let got64 = twin64.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        for (g, w) in got64.iter().zip(&want) {
            // The intervals pass through f32 (as the lengths do in rendering).
            assert!((g - w).abs() < 1e-6 * w.max(1e-2), "f64 twin: {g} vs {w}");
        }
    }

    #[test]
    fn fused_gradient_matches_its_twin_and_finite_differences() {
        let (n, s) = (30, 16);
        let (sigma, lengths) = inputs(n, s, 2);
        let var = Var::from_tensor(&sigma).unwrap();
        let mix = Tensor::rand(0.5f32, 1.5, (n, 1), &Device::Cpu).unwrap();
        let loss = |l: Tensor| l.mul(&mix).unwrap().sum_all().unwrap();
        let fused = loss(distortion_loss(var.as_tensor(), &lengths, SPACING).unwrap());
        let twin = loss(distortion_loss_tensor_ops(var.as_tensor(), &lengths, SPACING).unwrap());
        let (gf, gt) = (fused.backward().unwrap(), twin.backward().unwrap());
        let (gf, gt) = (gf.get(&var).unwrap(), gt.get(&var).unwrap());
        let d = max_abs_difference(gf, gt).unwrap();
        assert!(d < 1e-4, "fused and twin gradients differ by {d}");
        // Central differences of the f64 definition, for a handful of samples.
        let sig: Vec<f32> = sigma.flatten_all().unwrap().to_vec1().unwrap();
        let len: Vec<f32> = lengths.flatten_all().unwrap().to_vec1().unwrap();
        let m: Vec<f32> = mix.flatten_all().unwrap().to_vec1().unwrap();
        let total = |sig: &[f32]| -> f64 {
            reference(sig, &len, s)
                .iter()
                .zip(&m)
                .map(|(l, m)| l * f64::from(*m))
                .sum()
        };
        let gf: Vec<f32> = gf.flatten_all().unwrap().to_vec1().unwrap();
        for k in [0, 3, 17, 40, 101, 250, 333, 479] {
            let h = 1e-3 * sig[k].max(0.1);
            let (mut plus, mut minus) = (sig.clone(), sig.clone());
            plus[k] += h;
            minus[k] -= h;
            let fd = (total(&plus) - total(&minus)) / f64::from(2.0 * h);
            assert!(
                (f64::from(gf[k]) - fd).abs() < 2e-3 * fd.abs().max(1e-2),
                "σ{k}: {} vs {fd}",
                gf[k]
            );
        }
    }

    #[test]
    fn packed_kernel_matches_its_twin_values_and_gradients() {
        let (n, s) = (40, 12);
        let (_, lengths) = inputs(n, s, 3);
        // Two of every three samples listed, in a shuffled order.
        let mut index: Vec<u32> = (0..(n * s) as u32).filter(|i| i % 3 != 1).collect();
        index.reverse();
        let m = index.len();
        let dev = &Device::Cpu;
        let sigma = Var::from_tensor(&Tensor::rand(0.01f32, 3.0, (m, 1), dev).unwrap()).unwrap();
        let mix = Tensor::rand(0.5f32, 1.5, (n, 1), dev).unwrap();
        let packed = |index| PackedDensities {
            index,
            n_rays: n,
            density: sigma.as_tensor().clone(),
        };
        let run = |choice| {
            with_kernel_choice(choice, || {
                let l = distortion_loss_packed(packed(index.clone()), &lengths, SPACING).unwrap();
                let g = l.mul(&mix).unwrap().sum_all().unwrap().backward().unwrap();
                (l, g.get(&sigma).unwrap().clone())
            })
        };
        let (lf, gf) = run(KernelChoice::Fused);
        let (lt, gt) = run(KernelChoice::Generic);
        assert!(max_abs_difference(&lf, &lt).unwrap() < 1e-5);
        assert!(max_abs_difference(&gf, &gt).unwrap() < 1e-4);
        // Shared lengths `(1, S, 1)` give what the same lengths per ray give.
        let shared = lengths.narrow(0, 0, 1).unwrap();
        let per_ray = shared
            .broadcast_as((n, s, 1))
            .unwrap()
            .contiguous()
            .unwrap();
        let a = distortion_loss_packed(packed(index.clone()), &shared, SPACING);
        let b = distortion_loss_packed(packed(index), &per_ray, SPACING);
        assert_eq!(
            a.unwrap().to_vec2::<f32>().unwrap(),
            b.unwrap().to_vec2::<f32>().unwrap()
        );
    }
}
