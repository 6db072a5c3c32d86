//! Whole views (`render::view`) rendered in bands, on an SDF field.

use crate::sdf::SdfField;
use candle_core::Device;
use glam::DVec3;
use nerf_core::camera::surround_cameras;
use nerf_core::camera::Camera;
use nerf_core::rays::Rays;
use nerf_render::renderer::VolumeRenderer;
use nerf_render::sampler::StratifiedSampler;
use nerf_render::view::*;
use std::cell::Cell;

fn scene() -> (SdfField, StratifiedSampler, VolumeRenderer, Camera) {
    let field = super::renderer_tests::soft_unit_sphere();
    let sampler = StratifiedSampler::new(16, 0.1, 6.0).unwrap();
    let renderer = VolumeRenderer::new(64, false).unwrap();
    let camera = surround_cameras(3.0, 1, DVec3::Y, 1.0)[0].into();
    (field, sampler, renderer, camera)
}

#[test]
fn bands_give_the_whole_image_rays_give() {
    let (field, sampler, renderer, camera) = scene();
    let size = (13, 7);
    let whole = Rays::for_image(&camera, size.0, size.1, &Device::Cpu).unwrap();
    let pipeline = Pipeline::new(&field, &sampler, &renderer);
    let reference = pipeline.render(&whole).unwrap().color;
    let reference = reference.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    for band in [1, 5, 13, 64, 91, usize::MAX] {
        let never = Interrupt {
            band,
            stop: &|| false,
        };
        let view = render_view_interruptible(&pipeline, &camera, size, &Device::Cpu, never)
            .unwrap()
            .unwrap();
        assert_eq!(view.color.data, reference, "band {band}");
        assert_eq!(view.depth.len(), 13 * 7);
    }
}

#[test]
fn stop_is_asked_before_every_band_and_first_before_any_work() {
    let (field, sampler, renderer, camera) = scene();
    let pipeline = Pipeline::new(&field, &sampler, &renderer);
    let asked = Cell::new(0);
    // Stopped at once: asked once, nothing rendered (a 4096² image would take seconds).
    let at_once = Interrupt {
        band: 8192,
        stop: &|| {
            asked.set(asked.get() + 1);
            true
        },
    };
    let view =
        render_view_interruptible(&pipeline, &camera, (4096, 4096), &Device::Cpu, at_once).unwrap();
    assert!(view.is_none());
    assert_eq!(asked.get(), 1);
    // Stopped before the third band of 10 rays: asked three times.
    asked.set(0);
    let third = Interrupt {
        band: 10,
        stop: &|| {
            asked.set(asked.get() + 1);
            asked.get() == 3
        },
    };
    let view =
        render_view_interruptible(&pipeline, &camera, (10, 10), &Device::Cpu, third).unwrap();
    assert!(view.is_none());
    assert_eq!(asked.get(), 3);
}
