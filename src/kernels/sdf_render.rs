//! Rendering rays through an SDF volume in one fused CPU pass per ray, forward and backward:
//! sample points, σ and colour ([`SdfVolume::evaluate_point`]), and compositing
//! ([`crate::core::volume`]'s weights) without materialising the `(N, S, ·)` sample tensors.
//!
//! The forward pass runs the same scalar maths in the same order as its twin — the sampler's
//! [`crate::kernels::sample_points`], [`crate::kernels::sdf_volume`] and
//! [`crate::kernels::composite`] — so its colour, depth and opacity are bit for bit theirs.
//! A ray stops at the first sample where its transmittance is exactly 0: every later weight
//! is exactly 0, so nothing changes.
//!
//! The backward pass recomputes each ray, then, walking back, forms the compositing
//! gradients (`∂L/∂σ_i = Δ_i (T_{i+1} g_i − Σ_{j>i} w_j g_j)`, `∂L/∂c_i = w_i G`, see
//! [`crate::kernels::composite`]) and turns them into gradients of the packed parameters with
//! [`SdfVolume::sigma_with_partials`] and [`SdfVolume::colour_vjp`], summed in float64. Rays
//! and depths get no gradient (they are never trained; tracked ones take the twin).

use anyhow::Result;
use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::core::rays::Rays;
use crate::core::sdf::SdfVolume;
use crate::kernels::sdf_ray::{replay, reverse, RayScratch};
use crate::core::volume::{clamped_optical_depth, spacing};
use crate::kernels::sdf_volume::SdfTensors;
use crate::kernels::storage::contiguous_f32;
use crate::kernels::{needs_grad, use_fused};

/// Rays per parallel work item.
const RAYS_PER_TASK: usize = 64;


/// Colour `(N, 3)`, depth `(N, 1)` and opacity `(N, 1)` of `rays` (N) sampled at `lengths`
/// `(N, S, 1)` through `volume`, in one fused pass, with a backward pass to the volume's
/// parameters when any is tracked. `None` where the fused kernel does not apply (not the CPU
/// or not f32, generic kernels chosen, or the rays or depths tracked by autograd): then the
/// caller runs the twin.
pub fn sdf_render(
    rays: &Rays,
    lengths: &Tensor,
    volume: &SdfTensors,
) -> Result<Option<(Tensor, Tensor, Tensor)>> {
    let inputs = [&rays.origins, &rays.directions, lengths];
    if !use_fused(lengths) || !use_fused(&rays.origins) || inputs.into_iter().any(needs_grad) {
        return Ok(None);
    }
    let packed_rays = Tensor::cat(&[&rays.origins, &rays.directions], 1)?;
    let op = SdfRender {
        volume: volume.values()?,
    };
    let packed = volume.packed()?;
    let out = if volume.tensors().into_iter().any(needs_grad) {
        packed_rays.apply_op3(&lengths.contiguous()?, &packed, op)?
    } else {
        packed_rays.apply_op3_no_bwd(&lengths.contiguous()?, &packed, &op)?
    };
    Ok(Some((
        out.narrow(1, 0, 3)?,
        out.narrow(1, 3, 1)?,
        out.narrow(1, 4, 1)?,
    )))
}

/// `(rays (N, 6) = [origin, direction], lengths (N, S, 1), packed (P,))` → `(N, 5)` =
/// `[r, g, b, depth, opacity]`.
struct SdfRender {
    volume: SdfVolume,
}

impl SdfRender {
    /// Composites one ray into `out` (`[r, g, b, depth, opacity]`).
    fn forward_ray(&self, ray: &[f32], lengths: &[f32], out: &mut [f32]) {
        out.fill(0.0);
        let mut transmittance = 1f32;
        for (i, &t) in lengths.iter().enumerate() {
            let delta = spacing(lengths, i);
            let p = std::array::from_fn(|k| ray[k] + t * ray[3 + k]);
            let (sigma, colour) = self.volume.evaluate_point(p, delta);
            let a = (-clamped_optical_depth(sigma, delta)).exp();
            let w = transmittance * (1.0 - a);
            transmittance *= a;
            for c in 0..3 {
                out[c] += w * colour[c];
            }
            out[3] += w * t;
            out[4] += w;
            if transmittance == 0.0 {
                break;
            }
        }
    }

}

/// Sums per-task float64 gradient vectors into one float32 `(P,)` vector.
fn sum_parts(parts: Vec<Vec<f64>>, p: usize) -> Vec<f32> {
    let mut total = vec![0f64; p];
    for part in parts {
        for (t, v) in total.iter_mut().zip(part) {
            *t += v;
        }
    }
    total.into_iter().map(|v| v as f32).collect()
}

impl CustomOp3 for SdfRender {
    fn name(&self) -> &'static str {
        "fused-sdf-render"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        _s3: &CpuStorage,
        _l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let rays = contiguous_f32(s1, l1, "fused-sdf-render")?;
        let lengths = contiguous_f32(s2, l2, "fused-sdf-render")?;
        let (n, s, _) = l2.shape().dims3()?;
        if rays.len() != 6 * n {
            candle_core::bail!("fused-sdf-render: rays and lengths disagree in size");
        }
        let mut out = vec![0f32; 5 * n];
        out.par_chunks_mut(5 * RAYS_PER_TASK)
            .zip(rays.par_chunks(6 * RAYS_PER_TASK))
            .zip(lengths.par_chunks(s * RAYS_PER_TASK))
            .for_each(|((o, r), l)| {
                for ((o, r), l) in o
                    .chunks_exact_mut(5)
                    .zip(r.chunks_exact(6))
                    .zip(l.chunks_exact(s))
                {
                    self.forward_ray(r, l, o);
                }
            });
        Ok((CpuStorage::F32(out), Shape::from((n, 5))))
    }

    fn bwd(
        &self,
        rays: &Tensor,
        lengths: &Tensor,
        packed: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let g = rays.apply_op3_no_bwd(
            lengths,
            &grad_res.contiguous()?,
            &SdfRenderBackward {
                render: SdfRender {
                    volume: self.volume,
                },
                params: packed.elem_count(),
            },
        )?;
        Ok((None, None, Some(g)))
    }
}

/// The backward op: `(rays, lengths, ∂L/∂out (N, 5))` → `∂L/∂packed (P,)`.
struct SdfRenderBackward {
    render: SdfRender,
    params: usize,
}

impl CustomOp3 for SdfRenderBackward {
    fn name(&self) -> &'static str {
        "fused-sdf-render-backward"
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
        let name = "fused-sdf-render-backward";
        let rays = contiguous_f32(s1, l1, name)?;
        let lengths = contiguous_f32(s2, l2, name)?;
        let grad = contiguous_f32(s3, l3, name)?;
        let (_, s, _) = l2.shape().dims3()?;
        let p = self.params;
        let parts: Vec<Vec<f64>> = rays
            .par_chunks(6 * RAYS_PER_TASK)
            .zip(lengths.par_chunks(s * RAYS_PER_TASK))
            .zip(grad.par_chunks(5 * RAYS_PER_TASK))
            .map(|((r, l), g)| {
                let mut acc = vec![0f64; p];
                let mut sc = RayScratch::new(s);
                let volume = &self.render.volume;
                for ((r, l), g) in r
                    .chunks_exact(6)
                    .zip(l.chunks_exact(s))
                    .zip(g.chunks_exact(5))
                {
                    let (n, _) = replay(volume, r, l, &mut sc);
                    reverse(volume, &mut sc, n, g, &mut acc);
                }
                acc
            })
            .collect();
        let out = sum_parts(parts, p);
        Ok((CpuStorage::F32(out), Shape::from(p)))
    }
}

/// The mean squared error of the rendered colours of `rays` (N) sampled at `lengths`
/// `(N, S, 1)` against `target` `(N, 3)`, `mean((colour − target)²)` over all N·3 values
/// (composited onto white with `white_background`), as a scalar tensor whose backward pass
/// reaches the volume's parameters: a training step's loss in one fused pass per ray. The
/// gradient is computed with the loss, each ray replayed once in its own small scratch (no
/// second pass, no `(N, S, ·)` tensors), and handed back by the backward pass. `None` where
/// the fused kernel does not apply (see [`sdf_render`]); then the caller renders and forms
/// the loss with tensor ops, the twin.
pub fn sdf_render_mse(
    rays: &Rays,
    lengths: &Tensor,
    target: &Tensor,
    volume: &SdfTensors,
    white_background: bool,
) -> Result<Option<Tensor>> {
    let inputs = [&rays.origins, &rays.directions, lengths, target];
    if !use_fused(lengths) || !use_fused(&rays.origins) || inputs.into_iter().any(needs_grad) {
        return Ok(None);
    }
    let packed_rays = Tensor::cat(&[&rays.origins, &rays.directions, target], 1)?;
    let op = SdfRenderMse {
        render: SdfRender {
            volume: volume.values()?,
        },
        white_background,
        gradient: std::sync::Mutex::new(Vec::new()),
    };
    Ok(Some(packed_rays.apply_op3(
        &lengths.contiguous()?,
        &volume.packed()?,
        op,
    )?))
}

/// `(rays (N, 9) = [origin, direction, target], lengths (N, S, 1), packed (P,))` → the
/// scalar loss; the forward pass also computes `∂loss/∂packed`, which the backward pass
/// returns scaled by the upstream gradient.
struct SdfRenderMse {
    render: SdfRender,
    white_background: bool,
    gradient: std::sync::Mutex<Vec<f32>>,
}

impl SdfRenderMse {
    /// One ray's squared error, its gradient added to `acc`; `scale` is `1/(3N)`.
    fn ray(
        &self,
        ray: &[f32],
        lengths: &[f32],
        scale: f32,
        sc: &mut RayScratch,
        acc: &mut [f64],
    ) -> f64 {
        let volume = &self.render.volume;
        let (n, out) = replay(volume, &ray[..6], lengths, sc);
        let background = if self.white_background {
            1.0 - out[4]
        } else {
            0.0
        };
        let diff: [f32; 3] = std::array::from_fn(|c| out[c] + background - ray[6 + c]);
        let g: [f32; 3] = diff.map(|d| 2.0 * d * scale);
        let g_opacity = if self.white_background {
            -(g[0] + g[1] + g[2])
        } else {
            0.0
        };
        reverse(volume, sc, n, &[g[0], g[1], g[2], 0.0, g_opacity], acc);
        diff.iter().map(|d| (d * d) as f64).sum()
    }
}

impl CustomOp3 for SdfRenderMse {
    fn name(&self) -> &'static str {
        "fused-sdf-render-mse"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        _s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let name = "fused-sdf-render-mse";
        let rays = contiguous_f32(s1, l1, name)?;
        let lengths = contiguous_f32(s2, l2, name)?;
        let (n, s, _) = l2.shape().dims3()?;
        if rays.len() != 9 * n || n == 0 {
            candle_core::bail!("{name}: rays, targets and lengths disagree in size");
        }
        let p = l3.shape().elem_count();
        let scale = 1.0 / (3 * n) as f32;
        let parts: Vec<(f64, Vec<f64>)> = rays
            .par_chunks(9 * RAYS_PER_TASK)
            .zip(lengths.par_chunks(s * RAYS_PER_TASK))
            .map(|(r, l)| {
                let mut acc = vec![0f64; p];
                let mut sc = RayScratch::new(s);
                let err: f64 = r
                    .chunks_exact(9)
                    .zip(l.chunks_exact(s))
                    .map(|(r, l)| self.ray(r, l, scale, &mut sc, &mut acc))
                    .sum();
                (err, acc)
            })
            .collect();
        let loss = parts.iter().map(|(e, _)| e).sum::<f64>() / (3 * n) as f64;
        let gradient = sum_parts(parts.into_iter().map(|(_, g)| g).collect(), p);
        *self.gradient.lock().expect("gradient lock") = gradient;
        Ok((CpuStorage::F32(vec![loss as f32]), Shape::from(())))
    }

    fn bwd(
        &self,
        _rays: &Tensor,
        _lengths: &Tensor,
        packed: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let gradient = self.gradient.lock().expect("gradient lock").clone();
        let g =
            Tensor::from_vec(gradient, packed.shape(), packed.device())?.broadcast_mul(grad_res)?;
        Ok((None, None, Some(g)))
    }
}
