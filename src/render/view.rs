//! One camera's full image through the renderer.

use anyhow::Result;
use candle_core::{Device, Tensor};

use crate::core::camera::PerspectiveCamera;
use crate::core::image::RgbImage;
use crate::core::rays::Rays;
use crate::render::field::Field;
use crate::render::renderer::VolumeRenderer;
use crate::render::sampler::StratifiedSampler;
use crate::render::skipping::SampleCounts;

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

/// Renders one camera's full image (no jitter, no gradients needed).
pub fn render_view(
    field: &dyn Field,
    camera: &PerspectiveCamera,
    size: (usize, usize),
    sampler: &StratifiedSampler,
    renderer: &VolumeRenderer,
    device: &Device,
) -> Result<RenderedView> {
    let view = render_view_interruptible(
        field,
        camera,
        size,
        sampler,
        renderer,
        device,
        usize::MAX,
        &|| false,
    )?;
    Ok(view.expect("never interrupted"))
}

/// [`render_view`] in bands of `band` rays (row-major pixels), asking `stop` before each band:
/// `None` once it says yes, so that work nobody wants any more (a stale viewer frame, a client
/// that hung up) ends within one band. Each ray is rendered alone, so the image does not depend
/// on `band`.
#[allow(clippy::too_many_arguments)]
pub fn render_view_interruptible(
    field: &dyn Field,
    camera: &PerspectiveCamera,
    (width, height): (usize, usize),
    sampler: &StratifiedSampler,
    renderer: &VolumeRenderer,
    device: &Device,
    band: usize,
    stop: &dyn Fn() -> bool,
) -> Result<Option<RenderedView>> {
    camera.validate()?;
    let rays = Rays::for_image(camera, width, height, device)?;
    let n = rays.len();
    let band = band.max(1);
    let (mut colors, mut depths) = (Vec::new(), Vec::new());
    let mut samples = SampleCounts::default();
    let mut start = 0;
    while start < n {
        if stop() {
            return Ok(None);
        }
        let len = band.min(n - start);
        let out = renderer.render(field, sampler, &rays.narrow(start, len)?, None)?;
        colors.push(out.color);
        depths.push(out.depth);
        samples = samples + out.samples;
        start += len;
    }
    let flat = |parts: &[Tensor]| -> Result<Vec<f32>> {
        Ok(Tensor::cat(parts, 0)?.flatten_all()?.to_vec1::<f32>()?)
    };
    Ok(Some(RenderedView {
        color: RgbImage::new(width, height, flat(&colors)?)?,
        depth: flat(&depths)?,
        samples,
    }))
}
