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
use crate::core::sdf::{SdfVolume, SigmaPartials};
use crate::core::volume::{clamped_optical_depth, spacing, MAX_OPTICAL_DEPTH};
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

/// One sample of a ray as the backward pass needs it.
#[derive(Clone, Copy, Default)]
struct Sample {
    point: [f32; 3],
    delta: f32,
    weight: f32,
    /// Transmittance after the sample, `T_{i+1}`.
    after: f32,
    /// `g_i = Σ_c G_c c_ic + G_depth t_i + G_opacity`.
    g: f32,
    /// The optical depth is not clamped, so σ has a gradient.
    active: bool,
    partials: SigmaPartials,
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

    /// Recomputes one ray, keeping what the backward pass needs, up to the sample where its
    /// transmittance reaches 0; returns how many samples that is.
    fn replay_ray(
        &self,
        ray: &[f32],
        lengths: &[f32],
        grad: &[f32],
        samples: &mut [Sample],
    ) -> usize {
        let mut transmittance = 1f32;
        for (i, &t) in lengths.iter().enumerate() {
            let delta = spacing(lengths, i);
            let point = std::array::from_fn(|k| ray[k] + t * ray[3 + k]);
            let partials = self.volume.sigma_with_partials(point, delta);
            let colour = self.volume.colour_at(point);
            let a = (-clamped_optical_depth(partials.sigma, delta)).exp();
            let weight = transmittance * (1.0 - a);
            transmittance *= a;
            let raw = partials.sigma * delta;
            samples[i] = Sample {
                point,
                delta,
                weight,
                after: transmittance,
                g: (0..3).map(|c| grad[c] * colour[c]).sum::<f32>() + grad[3] * t + grad[4],
                active: delta != 0.0 && (0.0..MAX_OPTICAL_DEPTH as f32).contains(&raw),
                partials,
            };
            if transmittance == 0.0 {
                return i + 1;
            }
        }
        lengths.len()
    }

    /// Adds one ray's parameter gradients to `acc` (packed layout) for the output gradient
    /// `grad` (`[G_r, G_g, G_b, G_depth, G_opacity]`).
    fn backward_ray(
        &self,
        ray: &[f32],
        lengths: &[f32],
        grad: &[f32],
        samples: &mut [Sample],
        acc: &mut [f64],
    ) {
        let n = self.replay_ray(ray, lengths, grad, samples);
        let layout = self.volume.packed_layout();
        let mut suffix = 0f32;
        for s in samples[..n].iter().rev() {
            let d_tau = s.after * s.g - suffix;
            suffix += s.weight * s.g;
            if s.active {
                s.partials.add_to(s.delta * d_tau, layout, acc);
            }
            let g_colour = [grad[0], grad[1], grad[2]].map(|v| v * s.weight);
            self.volume.colour_vjp(s.point, g_colour, acc);
        }
    }
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
                let mut samples = vec![Sample::default(); s];
                for ((r, l), g) in r
                    .chunks_exact(6)
                    .zip(l.chunks_exact(s))
                    .zip(g.chunks_exact(5))
                {
                    self.render.backward_ray(r, l, g, &mut samples, &mut acc);
                }
                acc
            })
            .collect();
        let mut total = vec![0f64; p];
        for part in parts {
            for (t, v) in total.iter_mut().zip(part) {
                *t += v;
            }
        }
        let out: Vec<f32> = total.into_iter().map(|v| v as f32).collect();
        Ok((CpuStorage::F32(out), Shape::from(p)))
    }
}
