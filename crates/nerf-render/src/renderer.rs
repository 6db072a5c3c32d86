//! The homework's `VolumeRenderer`: sample → field → weights → aggregate, in chunks of rays.
//! The maths (spacing with `Δ_S = 1e10`, clamped optical depth, exclusive transmittance,
//! weights) is written once in [`nerf_core::volume`]; compositing runs through
//! [`nerf_kernels::composite`]. The same code path serves rendering and training
//! (everything is differentiable Candle ops or fused ops with backward passes).

use anyhow::{bail, Result};
use candle_core::{DType, Tensor};

use crate::field::{render_fused, samples_per_chunk, supports_packed, Composited, Field};
use crate::ray_sampler::RaySampler;
use crate::sampler::RaySamples;
use crate::skipping::SampleCounts;
use nerf_core::rays::Rays;
use nerf_core::volume::deltas;
use nerf_kernels::composite::composite;
use nerf_kernels::distortion_loss::distortion_loss;
use nerf_kernels::distortion_loss::RaySpacing;
use nerf_kernels::sample_points::sample_points;

/// Most samples drawn per chunk of rays when samples are skipped (an occupancy grid or early
/// termination): the chunk's rays are sized by the samples evaluated per segment, and this
/// bounds what a chunk holds when none of its rays terminates (2^23 samples: their depths,
/// march state and, at worst, evaluated values, well under 1 GiB).
pub const DRAWN_SAMPLES_PER_CHUNK: usize = 1 << 23;

/// A white background.
pub const WHITE: [f32; 3] = [1.0; 3];
/// A black background (the homework's default).
pub const BLACK: [f32; 3] = [0.0; 3];

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
    /// `(N, 1)` each ray's distortion loss ([`nerf_kernels::distortion_loss`]), when the
    /// renderer computes it ([`VolumeRenderer::distortion_loss`]).
    pub distortion: Option<Tensor>,
}

/// The homework's `VolumeRenderer`: renders rays in chunks of `chunk_size`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeRenderer {
    /// Rays rendered per chunk (the homework's `renderer.chunk_size`, at least 1).
    pub chunk_size: usize,
    /// The colour behind the scene: each ray's colour is `colour + (1 − opacity) · background`
    /// (black `[0, 0, 0]` adds nothing).
    pub background: [f32; 3],
    /// Transmittance below which a ray stops being evaluated (0 = off); see
    /// [`crate::skipping`]. Applies to NeRF fields.
    pub early_termination: f64,
    /// Also compute each ray's distortion loss (training with `training.distortion_loss`), in
    /// the sampler's spacing ([`RaySampler::spacing`]).
    pub distortion_loss: bool,
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
            background: if white_background { WHITE } else { BLACK },
            early_termination: 0.0,
            distortion_loss: false,
        })
    }

    /// The same renderer compositing onto `background` (RGB in [0, 1]).
    pub fn with_background(mut self, background: [f32; 3]) -> Self {
        self.background = background;
        self
    }

    /// Whether the background is white.
    pub fn is_white(&self) -> bool {
        self.background == WHITE
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
    pub fn skips_samples(&self, field: &dyn Field) -> bool {
        (field.occupancy().is_some() || self.early_termination > 0.0) && supports_packed(field)
    }

    /// Renders one chunk of rays (no chunking): sample → field → weights → aggregate, or the
    /// field's own fused pass ([`crate::field::FieldFastPaths::render_fused`]) when it has one
    /// for dense sampling.
    ///
    /// `rays`: N rays; returns colour `(N, 3)`, depth and opacity `(N, 1)`.
    pub(crate) fn render_chunk(
        &self,
        field: &dyn Field,
        sampler: &dyn RaySampler,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<RenderOutput> {
        let per_camera = match &rays.camera_index {
            Some(index) => field.for_cameras(index)?,
            None => None,
        };
        let field = per_camera.as_deref().unwrap_or(field);
        let spacing = self.distortion_spacing(sampler)?;
        if sampler.refines() {
            return self.render_refined(field, sampler, rays, jitter);
        }
        if !self.skips_samples(field) {
            let lengths = sampler.lengths(rays, jitter)?;
            if spacing.is_none() {
                if let Some(out) = render_fused(field, rays, &lengths)? {
                    return self.finish(out, SampleCounts::dense(lengths.elem_count()));
                }
            }
            return self.composite_samples(field, rays, lengths, spacing);
        }
        // (1, S, 1) without jitter: no per-ray copies of the same depths.
        let lengths = &sampler.compact_lengths(rays, jitter)?;
        let packed =
            crate::skipping::evaluate_packed(field, self.early_termination, rays, lengths)?;
        let counts = packed.counts;
        let distortion = match spacing {
            Some(spacing) => Some(packed.distortion(lengths, spacing)?),
            None => None,
        };
        // Composited straight from the packed values (the kernel scatters them into dense
        // tensors itself where it runs as tensor ops).
        let out = self.finish(packed.composite(lengths)?, counts)?;
        Ok(RenderOutput { distortion, ..out })
    }

    /// The spacing the distortion loss is measured in when the renderer computes it; an error
    /// when the sampler has none.
    fn distortion_spacing(&self, sampler: &dyn RaySampler) -> Result<Option<RaySpacing>> {
        if !self.distortion_loss {
            return Ok(None);
        }
        match sampler.spacing() {
            Some(spacing) => Ok(Some(spacing)),
            None => bail!(
                "training.distortion_loss needs a sampler of type stratified or \
                 depth_then_disparity (set it to 0 for this one)"
            ),
        }
    }

    /// Rendering at depths a sampler refines by looking at the field (coarse-to-fine): the
    /// stratified depths, refined ([`RaySampler::refine`]), rendered densely.
    ///
    /// `rays`: N rays; returns colour `(N, 3)`, depth and opacity `(N, 1)`.
    fn render_refined(
        &self,
        field: &dyn Field,
        sampler: &dyn RaySampler,
        rays: &Rays,
        mut jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<RenderOutput> {
        let rng = jitter.as_mut().map(|r| &mut **r as &mut dyn rand::RngCore);
        let drawn = sampler.lengths(rays, rng)?;
        let lengths = sampler.refine(field, rays, drawn, jitter)?;
        let mut out = self.composite_samples(field, rays, lengths, None)?;
        out.samples = SampleCounts {
            evaluated: rays.len() * sampler.evaluations_per_ray(),
            ..SampleCounts::dense(rays.len() * sampler.samples_per_ray())
        };
        Ok(out)
    }

    /// Dense rendering at `lengths` `(N, S, 1)`: sample points, evaluate the field, composite
    /// (and the distortion loss in `spacing`, when given).
    fn composite_samples(
        &self,
        field: &dyn Field,
        rays: &Rays,
        lengths: Tensor,
        spacing: Option<RaySpacing>,
    ) -> Result<RenderOutput> {
        let points = sample_points(&rays.origins, &rays.directions, &lengths)?;
        let samples = RaySamples { points, lengths };
        let deltas = deltas(&samples.lengths)?;
        let out = field.evaluate(&samples, &deltas, &rays.directions)?;
        let composited = composite(&out.density, &out.feature, &samples.lengths)?;
        let distortion = match spacing {
            Some(spacing) => Some(distortion_loss(&out.density, &samples.lengths, spacing)?),
            None => None,
        };
        let out = self.finish(
            composited,
            SampleCounts::dense(samples.lengths.elem_count()),
        )?;
        Ok(RenderOutput { distortion, ..out })
    }

    /// The output, composited onto the background (`colour + (1 − opacity) · background`).
    fn finish(&self, composited: Composited, samples: SampleCounts) -> Result<RenderOutput> {
        let Composited {
            mut color,
            depth,
            opacity,
        } = composited;
        if self.background != BLACK {
            let b = Tensor::new(&[self.background], color.device())?.to_dtype(color.dtype())?;
            color = color.add(&opacity.affine(-1.0, 1.0)?.broadcast_mul(&b)?)?;
        }
        Ok(RenderOutput {
            color,
            depth,
            opacity,
            samples,
            distortion: None,
        })
    }

    /// Rays [`VolumeRenderer::render`] renders at once: `chunk_size`, fewer where the field's
    /// samples at once (`samples_per_chunk`) require, and, when samples are skipped, no more
    /// than [`DRAWN_SAMPLES_PER_CHUNK`] drawn samples (at least 1 ray).
    pub fn rays_per_chunk(&self, field: &dyn Field, sampler: &dyn RaySampler) -> usize {
        // Samples evaluated at once per ray: a segment when skipping, else all of them.
        let skips = self.skips_samples(field);
        let drawn = sampler.drawn_per_ray();
        let per_ray = if skips {
            crate::skipping::segment_length(drawn, self.early_termination)
        } else {
            sampler.samples_per_ray()
        };
        let mut rays = self
            .chunk_size
            .min((samples_per_chunk(field) / per_ray).max(1));
        if skips {
            // A chunk's rays may all stay live to their last sample.
            rays = rays.min((DRAWN_SAMPLES_PER_CHUNK / drawn).max(1));
        }
        rays
    }

    /// Rays per band when an image of many rays is rendered band by band, at most about
    /// `max_rays` of them: a whole number of [`VolumeRenderer::rays_per_chunk`] chunks (at
    /// least one), so that the renderer sees the same chunks as with the whole image at once
    /// and the pixels are the same bit for bit.
    pub(crate) fn rays_per_band(
        &self,
        field: &dyn Field,
        sampler: &dyn RaySampler,
        max_rays: usize,
    ) -> usize {
        let chunk = self.rays_per_chunk(field, sampler);
        chunk * (max_rays / chunk).max(1)
    }

    /// Renders all rays, [`VolumeRenderer::rays_per_chunk`] at a time, and checks the result
    /// is finite.
    ///
    /// `rays`: N rays; returns colour `(N, 3)`, depth and opacity `(N, 1)`.
    pub fn render(
        &self,
        field: &dyn Field,
        sampler: &dyn RaySampler,
        rays: &Rays,
        mut jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<RenderOutput> {
        let n = rays.len();
        let chunk_size = self.rays_per_chunk(field, sampler);
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
                distortion: match parts
                    .iter()
                    .map(|o| o.distortion.clone())
                    .collect::<Option<Vec<_>>>()
                {
                    Some(d) => Some(Tensor::cat(&d, 0)?),
                    None => None,
                },
            }
        };
        ensure_finite(&out.color, "colour")?;
        ensure_finite(&out.depth, "depth")?;
        Ok(out)
    }
}

/// Fails with a clear message if `t` (any shape) holds a NaN or an infinity; `what` names it.
pub(crate) fn ensure_finite(t: &Tensor, what: &str) -> Result<()> {
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

    #[test]
    fn ensure_finite_catches_nan() {
        let t = Tensor::new(&[1f32, f32::NAN], &Device::Cpu).unwrap();
        assert!(ensure_finite(&t, "colour").is_err());
        let t = Tensor::new(&[1f32, 2.0], &Device::Cpu).unwrap();
        assert!(ensure_finite(&t, "colour").is_ok());
    }
}
