//! Rendering rays through an SDF volume in one fused CPU pass per ray, forward and backward:
//! sample points, transparency and colour, and compositing, without materialising the
//! `(N, S, ·)` sample tensors; per ray, blocks of samples are computed together so that the
//! work vectorises (`crate::sdf_ray`).
//!
//! The maths is the twin's — the sampler's points, `sdf_point::evaluate_point` and
//! [`nerf_core::volume`]'s weights, as [`crate::sample_points`],
//! [`crate::sdf_volume`] and [`crate::composite`] compute them — with two
//! float32-level differences: a sample's `e^{−τ}` is taken as `1 − density` (the twin's
//! `e^{−(−ln(1 − density)/Δ)·Δ}`, which is the same number up to rounding, and an opaque
//! sample's clamped τ the same 0), and `e^x` is `fastexp::exp_fast` (2 ulps).
//! Measured against the twin and the float64 reference in the tests. A ray stops after the
//! block in which its transmittance is exactly 0: every later weight is exactly 0.
//!
//! The backward pass recomputes each ray, then, walking back, forms the compositing
//! gradients (`∂L/∂τ_i = T_{i+1} g_i − Σ_{j>i} w_j g_j`, `∂L/∂c_i = w_i G`, see
//! [`crate::composite`]) and turns them into gradients of the packed parameters
//! (`sdf_point::transparency_from_distance`, `sdf_point::colour_factors`). Rays and
//! depths get no gradient (they are never trained; tracked ones take the twin).
//!
//! [`sdf_render_mse`] does a training step's loss in the same pass: the gradient is formed
//! with the loss, each ray replayed once.

use anyhow::Result;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

use crate::composite::Composited;
use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use crate::sdf_ray::{forward, replay, reverse, RayScratch};
use crate::sdf_volume::SdfTensors;
use crate::sdf_volume_grad::sum_blocks;
use crate::{needs_grad, use_fused};
use nerf_core::rays::Rays;
use nerf_core::sdf::SdfVolume;

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
) -> Result<Option<Composited>> {
    let inputs = [&rays.origins, &rays.directions, lengths];
    if !use_fused(lengths) || !use_fused(&rays.origins) || inputs.into_iter().any(needs_grad) {
        return Ok(None);
    }
    let packed_rays = Tensor::cat(&[&rays.origins, &rays.directions], 1)?;
    let op = Fused(SdfRender {
        volume: volume.values()?,
    });
    let packed = volume.packed()?;
    let out = if volume.tensors().into_iter().any(needs_grad) {
        packed_rays.apply_op3(&lengths.contiguous()?, &packed, op)?
    } else {
        packed_rays.apply_op3_no_bwd(&lengths.contiguous()?, &packed, &op)?
    };
    Ok(Some(Composited::from_columns(&out, 3)?))
}

/// `(rays (N, 6) = [origin, direction], lengths (N, S, 1), packed (P,))` → `(N, 5)` =
/// `[r, g, b, depth, opacity]`.
struct SdfRender {
    volume: SdfVolume,
}

impl CpuKernel<3> for SdfRender {
    const NAME: &'static str = "fused-sdf-render";

    fn cpu_forward(&self, [rays, lengths_in, _packed]: [CpuInput; 3]) -> KernelOutput {
        let rays = rays.f32(Self::NAME)?;
        let lengths = lengths_in.f32(Self::NAME)?;
        let (n, s, _) = lengths_in.shape().dims3()?;
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
                    o.copy_from_slice(&forward(&self.volume, r, l));
                }
            });
        Ok((out, Shape::from((n, 5))))
    }

    fn gradients(
        &self,
        [rays, lengths, packed]: [&Tensor; 3],
        grad: &Tensor,
    ) -> KernelGradients<3> {
        let g = rays.apply_op3_no_bwd(
            lengths,
            &grad.contiguous()?,
            &Fused(SdfRenderBackward {
                render: SdfRender {
                    volume: self.volume,
                },
                params: packed.elem_count(),
            }),
        )?;
        Ok([None, None, Some(g)])
    }
}

/// The backward op: `(rays, lengths, ∂L/∂out (N, 5))` → `∂L/∂packed (P,)`.
struct SdfRenderBackward {
    render: SdfRender,
    params: usize,
}

impl CpuKernel<3> for SdfRenderBackward {
    const NAME: &'static str = "fused-sdf-render-backward";

    fn cpu_forward(&self, inputs: [CpuInput; 3]) -> KernelOutput {
        let [rays, lengths, grad] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let (_, s, _) = inputs[1].shape().dims3()?;
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
        Ok((sum_blocks(parts, p), Shape::from(p)))
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
    let op = Fused(SdfRenderMse {
        render: SdfRender {
            volume: volume.values()?,
        },
        white_background,
        gradient: std::sync::Mutex::new(Vec::new()),
    });
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

impl CpuKernel<3> for SdfRenderMse {
    const NAME: &'static str = "fused-sdf-render-mse";

    fn cpu_forward(&self, [rays, lengths_in, packed]: [CpuInput; 3]) -> KernelOutput {
        let name = Self::NAME;
        let rays = rays.f32(name)?;
        let lengths = lengths_in.f32(name)?;
        let (n, s, _) = lengths_in.shape().dims3()?;
        if rays.len() != 9 * n || n == 0 {
            candle_core::bail!("{name}: rays, targets and lengths disagree in size");
        }
        let p = packed.shape().elem_count();
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
        let gradient = sum_blocks(parts.into_iter().map(|(_, g)| g).collect(), p);
        *self.gradient.lock().expect("gradient lock") = gradient;
        Ok((vec![loss as f32], Shape::from(())))
    }

    fn gradients(
        &self,
        [_rays, _lengths, packed]: [&Tensor; 3],
        grad: &Tensor,
    ) -> KernelGradients<3> {
        let gradient = self.gradient.lock().expect("gradient lock").clone();
        let g = Tensor::from_vec(gradient, packed.shape(), packed.device())?.broadcast_mul(grad)?;
        Ok([None, None, Some(g)])
    }
}
