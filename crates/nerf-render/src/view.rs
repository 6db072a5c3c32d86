//! One camera's full image through the renderer.

use std::sync::Arc;

use anyhow::Result;
use candle_core::Device;

use crate::bands::{band_rays, pixel_bands};
use crate::field::Field;
use crate::ray_sampler::RaySampler;
use crate::renderer::{RenderOutput, VolumeRenderer};
use crate::skipping::SampleCounts;
use nerf_core::camera::Camera;
use nerf_core::image::RgbImage;

/// One rendered view.
#[derive(Debug, Clone)]
pub struct RenderedView {
    /// `(H·W·3)` colour, row-major.
    pub color: RgbImage,
    /// `(H·W)` depth, row-major.
    pub depth: Vec<f32>,
    /// Samples drawn and evaluated for it.
    pub samples: SampleCounts,
}

/// What turns rays into pixels: the field, how its rays are sampled and how the samples are
/// composited. Copy it freely: it only borrows.
#[derive(Clone, Copy)]
pub struct Pipeline<'a> {
    /// The field evaluated at the samples.
    pub field: &'a dyn Field,
    /// Where along each ray the samples go.
    pub sampler: &'a dyn RaySampler,
    /// Chunking, compositing and background.
    pub renderer: &'a VolumeRenderer,
}

impl<'a> Pipeline<'a> {
    /// The pipeline of `field`, `sampler` and `renderer`.
    pub fn new(
        field: &'a dyn Field,
        sampler: &'a dyn RaySampler,
        renderer: &'a VolumeRenderer,
    ) -> Self {
        Self {
            field,
            sampler,
            renderer,
        }
    }

    /// Renders `rays` (N rays) without jitter: colour `(N, 3)`, depth and opacity `(N, 1)`.
    pub fn render(&self, rays: &nerf_core::rays::Rays) -> Result<RenderOutput> {
        self.renderer.render(self.field, self.sampler, rays, None)
    }

    /// The rays per band that [`render_view`] uses: whole chunks, about
    /// [`crate::bands::BAND_RAYS`] rays.
    pub(crate) fn band_rays(&self) -> usize {
        self.rays_per_band(crate::bands::BAND_RAYS)
    }

    /// Rays per band of about `max_rays`, a whole number of this pipeline's chunks
    /// (`VolumeRenderer::rays_per_band`).
    pub fn rays_per_band(&self, max_rays: usize) -> usize {
        self.renderer
            .rays_per_band(self.field, self.sampler, max_rays)
    }
}

/// The owned, field-independent half of a [`Pipeline`]: a sampler and a renderer, paired with
/// any field by [`RenderSettings::with`].
#[derive(Clone)]
pub struct RenderSettings {
    /// Where along each ray the samples go.
    pub sampler: Arc<dyn RaySampler>,
    /// Chunking, compositing and background.
    pub renderer: VolumeRenderer,
}

impl RenderSettings {
    /// The pipeline that renders `field` with these settings.
    pub fn with<'a>(&'a self, field: &'a dyn Field) -> Pipeline<'a> {
        Pipeline::new(field, &*self.sampler, &self.renderer)
    }
}

/// When a view rendered in bands may stop early: before each band of `band` rays,
/// `stop()` is asked, and a yes ends the render.
#[derive(Clone, Copy)]
pub struct Interrupt<'a> {
    /// Rays per band (at least 1; whole chunks keep pixels identical, see
    /// `VolumeRenderer::rays_per_band`).
    pub band: usize,
    /// Asked before each band; `true` abandons the view.
    pub stop: &'a dyn Fn() -> bool,
}

/// Renders one camera's full image of `size` = (W, H) pixels (no jitter, no gradients
/// needed): colour `(H·W·3)` and depth `(H·W)`, row-major.
pub fn render_view(
    pipeline: &Pipeline,
    camera: &Camera,
    size: (usize, usize),
    device: &Device,
) -> Result<RenderedView> {
    nerf_core::allocator::ensure_allocator_tuned();
    let never = Interrupt {
        band: pipeline.band_rays(),
        stop: &|| false,
    };
    let view = render_view_interruptible(pipeline, camera, size, device, never)?;
    Ok(view.expect("never interrupted"))
}

/// [`render_view`] in bands of `interrupt.band` rays (row-major pixels), asking
/// `interrupt.stop` before each band, before any of its rays is made: `None` once it says
/// yes, so that work nobody wants any more (a stale viewer frame, a client that hung up) ends
/// within one band and costs nothing when it is stopped before it starts. Only one band's rays
/// exist at a time; the image is written into its final buffers as the bands come. Each ray
/// is rendered alone, so the image does not depend on the band size.
pub fn render_view_interruptible(
    pipeline: &Pipeline,
    camera: &Camera,
    (width, height): (usize, usize),
    device: &Device,
    interrupt: Interrupt,
) -> Result<Option<RenderedView>> {
    camera.validate()?;
    let n = width * height;
    let mut color = Vec::new();
    let mut depth = Vec::new();
    let mut samples = SampleCounts::default();
    for pixels in pixel_bands(n, interrupt.band) {
        if (interrupt.stop)() {
            return Ok(None);
        }
        let rays = band_rays(camera, (width, height), pixels, device)?;
        let out = pipeline.render(&rays)?;
        if color.is_empty() {
            color.reserve_exact(3 * n);
            depth.reserve_exact(n);
        }
        color.extend(out.color.flatten_all()?.to_vec1::<f32>()?);
        depth.extend(out.depth.flatten_all()?.to_vec1::<f32>()?);
        samples = samples + out.samples;
    }
    Ok(Some(RenderedView {
        color: RgbImage::new(width, height, color)?,
        depth,
        samples,
    }))
}
