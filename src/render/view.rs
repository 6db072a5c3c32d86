//! One camera's full image through the renderer.

use anyhow::Result;
use candle_core::Device;

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
    (width, height): (usize, usize),
    sampler: &StratifiedSampler,
    renderer: &VolumeRenderer,
    device: &Device,
) -> Result<RenderedView> {
    camera.validate()?;
    let rays = Rays::for_image(camera, width, height, device)?;
    let out = renderer.render(field, sampler, &rays, None)?;
    let color = out.color.flatten_all()?.to_vec1::<f32>()?;
    let depth = out.depth.flatten_all()?.to_vec1::<f32>()?;
    Ok(RenderedView {
        color: RgbImage::new(width, height, color)?,
        depth,
        samples: out.samples,
    })
}
