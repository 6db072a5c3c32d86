//! Fused volume compositing on the CPU: weights and their weighted sums in one pass per ray,
//! with a hand-written backward pass so training uses the same code path as rendering.
//!
//! Inputs: density σ `(N, S, 1)`, spacings Δ `(N, S, 1)`, values v `(N, S, K)`.
//! Output `(N, K + 1)`: `Σ_i w_i v_ik` for each k, then the opacity `Σ_i w_i`, with
//! `τ_i = clamp(σ_i Δ_i, 0, MAX_OPTICAL_DEPTH)`, `T_i = exp(−Σ_{j<i} τ_j)`,
//! `w_i = T_i (1 − e^{−τ_i})` — the same maths as [`crate::renderer::weights`].
//!
//! Backward, with `g_i = Σ_k G_k v_ik + G_K` for the output gradient G:
//! `∂L/∂v_ik = w_i G_k` and `∂L/∂τ_i = T_{i+1} g_i − Σ_{j>i} w_j g_j`, so
//! `∂L/∂σ_i = Δ_i ∂L/∂τ_i` for `0 ≤ σΔ < MAX_OPTICAL_DEPTH` and 0 above, where the clamp holds
//! the optical depth constant.

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::renderer::MAX_OPTICAL_DEPTH;

/// Rays per parallel work item.
const RAYS_PER_TASK: usize = 256;

/// Optical depth of one sample, clamped as in [`crate::renderer::optical_depth`].
#[inline]
pub fn clamped_optical_depth(sigma: f32, delta: f32) -> f32 {
    (sigma * delta).clamp(0.0, MAX_OPTICAL_DEPTH as f32)
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

fn contiguous<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> candle_core::Result<&'a [f32]> {
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&s.as_slice::<f32>()?[a..b]),
        None => candle_core::bail!("composite: {what} must be contiguous"),
    }
}

/// The forward op: `(σ, Δ, v) → (N, K + 1)`.
pub struct Composite;

impl CustomOp3 for Composite {
    fn name(&self) -> &'static str {
        "volume-composite"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let sigma = contiguous(s1, l1, "density")?;
        let delta = contiguous(s2, l2, "deltas")?;
        let values = contiguous(s3, l3, "values")?;
        let (n, s, k) = l3.shape().dims3()?;
        if sigma.len() != n * s || delta.len() != n * s {
            candle_core::bail!("composite: density, deltas and values disagree in shape");
        }
        let mut out = vec![0f32; n * (k + 1)];
        out.par_chunks_mut(RAYS_PER_TASK * (k + 1))
            .enumerate()
            .for_each(|(task, out)| {
                let mut tau = vec![0f32; s];
                let mut w = vec![0f32; s];
                let mut t_after = vec![0f32; s];
                for (r, o) in out.chunks_exact_mut(k + 1).enumerate() {
                    let ray = task * RAYS_PER_TASK + r;
                    let base = ray * s;
                    for i in 0..s {
                        tau[i] = clamped_optical_depth(sigma[base + i], delta[base + i]);
                    }
                    ray_weights(&tau, &mut w, &mut t_after);
                    o.fill(0.0);
                    for i in 0..s {
                        let v = &values[(base + i) * k..(base + i + 1) * k];
                        for c in 0..k {
                            o[c] += w[i] * v[c];
                        }
                        o[k] += w[i];
                    }
                }
            });
        Ok((CpuStorage::F32(out), Shape::from((n, k + 1))))
    }

    fn bwd(
        &self,
        sigma: &Tensor,
        delta: &Tensor,
        values: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let grads = Tensor::cat(
            &[
                &sigma.flatten_all()?,
                &delta.flatten_all()?,
                &values.flatten_all()?,
                &grad_res.flatten_all()?,
            ],
            0,
        )?;
        let (n, s, k) = values.dims3()?;
        let both = grads.apply_op1_no_bwd(&CompositeBackward { n, s, k })?;
        let grad_sigma = both.narrow(0, 0, n * s)?.reshape((n, s, 1))?;
        let grad_values = both.narrow(0, n * s, n * s * k)?.reshape((n, s, k))?;
        Ok((Some(grad_sigma), None, Some(grad_values)))
    }
}

/// The backward op; input is `[σ, Δ, v, G]` flattened and concatenated, output
/// `[∂L/∂σ, ∂L/∂v]` flattened and concatenated.
struct CompositeBackward {
    n: usize,
    s: usize,
    k: usize,
}

impl candle_core::CustomOp1 for CompositeBackward {
    fn name(&self) -> &'static str {
        "volume-composite-backward"
    }

    fn cpu_fwd(&self, st: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let all = contiguous(st, l, "gradient input")?;
        let (n, s, k) = (self.n, self.s, self.k);
        let (sigma, rest) = all.split_at(n * s);
        let (delta, rest) = rest.split_at(n * s);
        let (values, grad) = rest.split_at(n * s * k);
        let mut out = vec![0f32; n * s * (k + 1)];
        let (g_sigma, g_values) = out.split_at_mut(n * s);
        g_sigma
            .par_chunks_mut(RAYS_PER_TASK * s)
            .zip(g_values.par_chunks_mut(RAYS_PER_TASK * s * k))
            .enumerate()
            .for_each(|(task, (gs, gv))| {
                let mut tau = vec![0f32; s];
                let mut w = vec![0f32; s];
                let mut t_after = vec![0f32; s];
                let mut g = vec![0f64; s];
                for (r, (gs, gv)) in gs
                    .chunks_exact_mut(s)
                    .zip(gv.chunks_exact_mut(s * k))
                    .enumerate()
                {
                    let ray = task * RAYS_PER_TASK + r;
                    let base = ray * s;
                    let go = &grad[ray * (k + 1)..(ray + 1) * (k + 1)];
                    for i in 0..s {
                        tau[i] = clamped_optical_depth(sigma[base + i], delta[base + i]);
                    }
                    ray_weights(&tau, &mut w, &mut t_after);
                    for i in 0..s {
                        let v = &values[(base + i) * k..(base + i + 1) * k];
                        let mut gi = go[k] as f64;
                        for c in 0..k {
                            gi += (go[c] * v[c]) as f64;
                            gv[i * k + c] = w[i] * go[c];
                        }
                        g[i] = gi;
                    }
                    // Suffix sums Σ_{j>i} w_j g_j, walking backwards.
                    let mut suffix = 0f64;
                    for i in (0..s).rev() {
                        let d_tau = t_after[i] as f64 * g[i] - suffix;
                        suffix += w[i] as f64 * g[i];
                        let raw = sigma[base + i] * delta[base + i];
                        let active = (0.0..MAX_OPTICAL_DEPTH as f32).contains(&raw);
                        gs[i] = if active {
                            (delta[base + i] as f64 * d_tau) as f32
                        } else {
                            0.0
                        };
                    }
                }
            });
        Ok((CpuStorage::F32(out), Shape::from(n * s * (k + 1))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::renderer::{aggregate, weights};
    use candle_core::{Device, Var};

    /// Random inputs; `zero` is the value used for the 30% empty samples.
    fn inputs(n: usize, s: usize, k: usize, seed: u64, zero: f32) -> (Tensor, Tensor, Tensor) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let sigma: Vec<f32> = (0..n * s)
            .map(|_| {
                if rng.random::<f32>() < 0.3 {
                    zero
                } else {
                    rng.random::<f32>() * 4.0
                }
            })
            .collect();
        let mut lengths = Vec::new();
        for _ in 0..n {
            let mut t = 0.5f32;
            for _ in 0..s {
                t += rng.random::<f32>() * 0.2;
                lengths.push(t);
            }
        }
        let values: Vec<f32> = (0..n * s * k).map(|_| rng.random::<f32>()).collect();
        let dev = &Device::Cpu;
        let l = Tensor::from_vec(lengths, (n, s, 1), dev).unwrap();
        let d = crate::renderer::deltas(&l).unwrap();
        (
            Tensor::from_vec(sigma, (n, s, 1), dev).unwrap(),
            d,
            Tensor::from_vec(values, (n, s, k), dev).unwrap(),
        )
    }

    #[test]
    fn forward_matches_tensor_ops() {
        let (sigma, d, v) = inputs(300, 9, 4, 1, 0.0);
        let fused = sigma.apply_op3(&d, &v, Composite).unwrap();
        assert_eq!(fused.dims(), &[300, 5]);
        let w = weights(&sigma, &d).unwrap();
        let reference = Tensor::cat(&[aggregate(&w, &v).unwrap(), w.sum(1).unwrap()], 1).unwrap();
        let diff = fused
            .sub(&reference)
            .unwrap()
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!(diff < 1e-5, "max diff {diff}");
    }

    #[test]
    fn backward_matches_tensor_ops_autodiff() {
        // Exact zeros are avoided: Candle's clamp splits the gradient at a tie.
        let (sigma, d, v) = inputs(70, 12, 3, 2, 1e-4);
        let sv = Var::from_tensor(&sigma).unwrap();
        let vv = Var::from_tensor(&v).unwrap();
        // A loss that weights every output differently.
        let mix = Tensor::new(&[[0.3f32, -1.2, 0.7, 2.0]], &Device::Cpu).unwrap();
        let loss_of = |out: Tensor| out.broadcast_mul(&mix).unwrap().sum_all().unwrap();
        let fused = loss_of(
            sv.as_tensor()
                .apply_op3(&d, vv.as_tensor(), Composite)
                .unwrap(),
        );
        let gf = fused.backward().unwrap();
        let w = weights(sv.as_tensor(), &d).unwrap();
        let reference = loss_of(
            Tensor::cat(
                &[aggregate(&w, vv.as_tensor()).unwrap(), w.sum(1).unwrap()],
                1,
            )
            .unwrap(),
        );
        let gr = reference.backward().unwrap();
        for var in [&sv, &vv] {
            let a = gf.get(var.as_tensor()).unwrap();
            let b = gr.get(var.as_tensor()).unwrap();
            let diff = a
                .sub(b)
                .unwrap()
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            let scale = b
                .abs()
                .unwrap()
                .max_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap()
                .max(1.0);
            assert!(
                diff <= 1e-4 * scale,
                "gradient differs by {diff} (scale {scale})"
            );
        }
    }
}
