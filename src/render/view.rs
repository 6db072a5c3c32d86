//! One camera's full image through the renderer.

use anyhow::Result;
use candle_core::Device;

use crate::core::camera_model::CameraModel;
use crate::core::image::RgbImage;
use crate::render::bands::{band_rays, pixel_bands};
use crate::render::field::Field;
use crate::render::ray_sampler::RaySampler;
use crate::render::renderer::VolumeRenderer;
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
    camera: &dyn CameraModel,
    size: (usize, usize),
    sampler: &dyn RaySampler,
    renderer: &VolumeRenderer,
    device: &Device,
) -> Result<RenderedView> {
    crate::core::allocator::ensure_allocator_tuned();
    let view = render_view_interruptible(
        field,
        camera,
        size,
        sampler,
        renderer,
        device,
        renderer.rays_per_band(field, sampler, crate::render::bands::BAND_RAYS),
        &|| false,
    )?;
    Ok(view.expect("never interrupted"))
}

/// [`render_view`] in bands of `band` rays (row-major pixels), asking `stop` before each band,
/// before any of its rays is made: `None` once it says yes, so that work nobody wants any more
/// (a stale viewer frame, a client that hung up) ends within one band and costs nothing when
/// it is stopped before it starts. Only one band's rays exist at a time; the image is written
/// into its final buffers as the bands come. Each ray is rendered alone, so the image does not
/// depend on `band`.
#[allow(clippy::too_many_arguments)]
pub fn render_view_interruptible(
    field: &dyn Field,
    camera: &dyn CameraModel,
    (width, height): (usize, usize),
    sampler: &dyn RaySampler,
    renderer: &VolumeRenderer,
    device: &Device,
    band: usize,
    stop: &dyn Fn() -> bool,
) -> Result<Option<RenderedView>> {
    camera.validate()?;
    let n = width * height;
    let mut color = Vec::new();
    let mut depth = Vec::new();
    let mut samples = SampleCounts::default();
    for pixels in pixel_bands(n, band) {
        if stop() {
            return Ok(None);
        }
        let rays = band_rays(camera, (width, height), pixels, device)?;
        let out = renderer.render(field, sampler, &rays, None)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::camera::surround_cameras;
    use crate::core::camera::PerspectiveCamera;
    use crate::core::rays::Rays;
    use crate::field::sdf::SdfField;
    use crate::render::sampler::StratifiedSampler;
    use glam::DVec3;
    use std::cell::Cell;

    fn scene() -> (
        SdfField,
        StratifiedSampler,
        VolumeRenderer,
        PerspectiveCamera,
    ) {
        let field = crate::render::renderer::coarse_to_fine_tests::soft_unit_sphere();
        let sampler = StratifiedSampler::new(16, 0.1, 6.0).unwrap();
        let renderer = VolumeRenderer::new(64, false).unwrap();
        let camera = surround_cameras(3.0, 1, DVec3::Y, 1.0)[0];
        (field, sampler, renderer, camera)
    }

    #[test]
    fn bands_give_the_whole_image_rays_give() {
        let (field, sampler, renderer, camera) = scene();
        let size = (13, 7);
        let whole = Rays::for_image(&camera, size.0, size.1, &Device::Cpu).unwrap();
        let reference = renderer.render(&field, &sampler, &whole, None).unwrap();
        let reference = reference
            .color
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        for band in [1, 5, 13, 64, 91, usize::MAX] {
            let view = render_view_interruptible(
                &field,
                &camera,
                size,
                &sampler,
                &renderer,
                &Device::Cpu,
                band,
                &|| false,
            )
            .unwrap()
            .unwrap();
            assert_eq!(view.color.data, reference, "band {band}");
            assert_eq!(view.depth.len(), 13 * 7);
        }
    }

    #[test]
    fn stop_is_asked_before_every_band_and_first_before_any_work() {
        let (field, sampler, renderer, camera) = scene();
        let asked = Cell::new(0);
        // Stopped at once: asked once, nothing rendered (a 4096² image would take seconds).
        let view = render_view_interruptible(
            &field,
            &camera,
            (4096, 4096),
            &sampler,
            &renderer,
            &Device::Cpu,
            8192,
            &|| {
                asked.set(asked.get() + 1);
                true
            },
        )
        .unwrap();
        assert!(view.is_none());
        assert_eq!(asked.get(), 1);
        // Stopped before the third band of 10 rays: asked three times.
        asked.set(0);
        let view = render_view_interruptible(
            &field,
            &camera,
            (10, 10),
            &sampler,
            &renderer,
            &Device::Cpu,
            10,
            &|| {
                asked.set(asked.get() + 1);
                asked.get() == 3
            },
        )
        .unwrap();
        assert!(view.is_none());
        assert_eq!(asked.get(), 3);
    }
}
