//! Emission–absorption volume rendering with exclusive transmittance.
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

use anyhow::{bail, Result};
use candle_core::{DType, Tensor, D};

use crate::core::rays::Rays;
use crate::render::field::Field;
use crate::render::sampler::StratifiedSampler;
use crate::render::skipping::SampleCounts;

/// Spacing used for the last sample of every ray, as in the homework.
pub const LAST_DELTA: f64 = 1e10;

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
pub fn optical_depth(density: &Tensor, deltas: &Tensor) -> Result<Tensor> {
    let tau = density.mul(deltas)?.clamp(0f32, MAX_OPTICAL_DEPTH as f32)?;
    // Zero spacing: zero optical depth, even where σ is ∞ or NaN (σ = −ln(1 − d)/0).
    let zero_spacing = deltas.eq(0f64)?;
    Ok(zero_spacing.where_cond(&tau.zeros_like()?, &tau)?)
}

/// Exclusive transmittance `T_i = exp(−Σ_{j<i} τ_j)` from optical depths `τ`.
///
/// `optical_depth`: `(N, S, 1)`; returns `(N, S, 1)` with `T_1 = 1`.
pub fn transmittance(optical_depth: &Tensor) -> Result<Tensor> {
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

/// Colour, depth and opacity of each ray from its samples: the weights and their weighted sums.
/// On the CPU with f32 data this is the fused kernel of [`crate::composite`] (forward and
/// backward); elsewhere the tensor ops [`weights`] and [`aggregate`].
///
/// `density`, `deltas`, `lengths`: `(N, S, 1)`; `feature`: `(N, S, C)`. Returns colour `(N, C)`,
/// depth `(N, 1)` and opacity `(N, 1)`.
pub fn composite(
    density: &Tensor,
    deltas: &Tensor,
    feature: &Tensor,
    lengths: &Tensor,
) -> Result<RenderOutput> {
    let c = feature.dim(2)?;
    if density.device().is_cpu() && density.dtype() == DType::F32 {
        // The kernel derives the same deltas from the lengths itself; σ and the features are
        // read through their strides, so the fused field's output is not copied.
        let out = density.apply_op3(lengths, feature, crate::kernels::composite::Composite)?;
        return Ok(RenderOutput {
            color: out.narrow(1, 0, c)?,
            depth: out.narrow(1, c, 1)?,
            opacity: out.narrow(1, c + 1, 1)?,
            samples: SampleCounts::dense(density.elem_count()),
        });
    }
    let w = weights(density, deltas)?;
    Ok(RenderOutput {
        color: aggregate(&w, feature)?,
        depth: aggregate(&w, lengths)?,
        opacity: w.sum(1)?,
        samples: SampleCounts::dense(density.elem_count()),
    })
}

/// What the renderer produces for a batch of N rays.
#[derive(Debug, Clone)]
pub struct RenderOutput {
    /// `(N, 3)` colour (the aggregated field feature).
    pub color: Tensor,
    /// `(N, 1)` expected depth `Σ w t`.
    pub depth: Tensor,
    /// `(N, 1)` opacity `Σ w`.
    pub opacity: Tensor,
    /// Samples drawn and evaluated (see [`crate::skipping`]).
    pub samples: SampleCounts,
}

/// The homework's `VolumeRenderer`: renders rays in chunks of `chunk_size`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeRenderer {
    pub chunk_size: usize,
    /// Composite onto white (`colour + 1 − opacity`) instead of black.
    pub white_background: bool,
    /// Transmittance below which a ray stops being evaluated (0 = off); see
    /// [`crate::skipping`]. Applies to NeRF fields.
    pub early_termination: f64,
}

impl VolumeRenderer {
    /// A renderer of `chunk_size` rays at a time (at least 1), compositing on white when
    /// `white_background`; early termination off.
    pub fn new(chunk_size: usize, white_background: bool) -> Result<Self> {
        if chunk_size == 0 {
            bail!("renderer.chunk_size must be at least 1");
        }
        Ok(Self {
            chunk_size,
            white_background,
            early_termination: 0.0,
        })
    }

    /// The same renderer with early ray termination at transmittance `threshold` (0 = off).
    pub fn with_early_termination(mut self, threshold: f64) -> Result<Self> {
        if !(0.0..1.0).contains(&threshold) {
            bail!("renderer.early_termination must be in [0, 1) (got {threshold})");
        }
        self.early_termination = threshold;
        Ok(self)
    }

    /// Whether `field` is rendered through [`crate::skipping`] (an occupancy grid or early
    /// termination is in use) rather than evaluated densely.
    pub fn skips_samples(&self, field: &Field) -> bool {
        matches!(field, Field::Nerf { occupancy, .. } if occupancy.is_some() || self.early_termination > 0.0)
    }

    /// Renders one chunk of rays (no chunking): sample → field → weights → aggregate.
    ///
    /// `rays`: N rays; returns colour `(N, 3)`, depth and opacity `(N, 1)`.
    pub fn render_chunk(
        &self,
        field: &Field,
        sampler: &StratifiedSampler,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<RenderOutput> {
        let samples = sampler.sample(rays, jitter)?;
        let deltas = deltas(&samples.lengths)?;
        let (out, counts) = match field {
            Field::Nerf {
                model,
                density_noise,
                occupancy,
            } if self.skips_samples(field) => crate::render::skipping::evaluate_skipping(
                model,
                *density_noise,
                occupancy.as_deref(),
                self.early_termination,
                &samples,
                &rays.directions,
            )?,
            _ => (
                field.evaluate(&samples, &deltas, &rays.directions)?,
                SampleCounts::dense(samples.lengths.elem_count()),
            ),
        };
        let RenderOutput {
            mut color,
            depth,
            opacity,
            ..
        } = composite(&out.density, &deltas, &out.feature, &samples.lengths)?;
        if self.white_background {
            color = color.add(&opacity.affine(-1.0, 1.0)?.broadcast_as(color.shape())?)?;
        }
        Ok(RenderOutput {
            color,
            depth,
            opacity,
            samples: counts,
        })
    }

    /// Renders all rays, `chunk_size` at a time (fewer where the field's
    /// [`Field::max_samples_per_chunk`] requires), and checks the result is finite.
    ///
    /// `rays`: N rays; returns colour `(N, 3)`, depth and opacity `(N, 1)`.
    pub fn render(
        &self,
        field: &Field,
        sampler: &StratifiedSampler,
        rays: &Rays,
        mut jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<RenderOutput> {
        let n = rays.len();
        // Samples evaluated at once per ray: a segment when skipping, else all of them.
        let per_ray = if self.skips_samples(field) {
            crate::render::skipping::segment_length(sampler.n_pts_per_ray, self.early_termination)
        } else {
            sampler.n_pts_per_ray
        };
        let chunk_size = self
            .chunk_size
            .min((field.max_samples_per_chunk() / per_ray).max(1));
        let mut parts = Vec::with_capacity(n.div_ceil(chunk_size));
        let mut start = 0;
        while start < n {
            let len = chunk_size.min(n - start);
            let chunk = rays.narrow(start, len)?;
            let rng = jitter.as_mut().map(|r| &mut **r as &mut dyn rand::RngCore);
            parts.push(self.render_chunk(field, sampler, &chunk, rng)?);
            start += len;
        }
        let out = if parts.len() == 1 {
            parts.pop().expect("one chunk")
        } else {
            let cat = |f: fn(&RenderOutput) -> &Tensor| -> Result<Tensor> {
                Ok(Tensor::cat(&parts.iter().map(f).collect::<Vec<_>>(), 0)?)
            };
            RenderOutput {
                color: cat(|o| &o.color)?,
                depth: cat(|o| &o.depth)?,
                opacity: cat(|o| &o.opacity)?,
                samples: parts
                    .iter()
                    .fold(SampleCounts::default(), |a, o| a + o.samples),
            }
        };
        ensure_finite(&out.color, "colour")?;
        ensure_finite(&out.depth, "depth")?;
        Ok(out)
    }
}

/// Fails with a clear message if `t` (any shape) holds a NaN or an infinity; `what` names it.
pub fn ensure_finite(t: &Tensor, what: &str) -> Result<()> {
    let total = t.to_dtype(DType::F64)?.sum_all()?.to_scalar::<f64>()?;
    if !total.is_finite() {
        bail!("the renderer produced a non-finite {what} (NaN or infinity); check the field's density and feature");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

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

    #[test]
    fn ensure_finite_catches_nan() {
        let t = Tensor::new(&[1f32, f32::NAN], &Device::Cpu).unwrap();
        assert!(ensure_finite(&t, "colour").is_err());
        let t = Tensor::new(&[1f32, 2.0], &Device::Cpu).unwrap();
        assert!(ensure_finite(&t, "colour").is_ok());
    }
}
