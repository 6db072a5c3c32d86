//! The renderer (`render::renderer`) on SDF fields: coarse-to-fine sampling and chunking.

use crate::sdf::SdfField;
use candle_core::Device;
use candle_core::Tensor;
use nerf_core::rays::Rays;
use nerf_core::sdf::{Sdf, SdfVolume};
use nerf_kernels::test_support::abs_sum;
use nerf_render::hierarchical::CoarseToFineSampler;
use nerf_render::ray_sampler::RaySampler;
use nerf_render::renderer::*;
use nerf_render::sampler::StratifiedSampler;

/// A rainbow unit sphere at the origin with a soft surface (β = 0.05): the test scene of
/// the renderer's and the view's tests.
pub(super) fn soft_unit_sphere() -> SdfField {
    let volume = SdfVolume {
        sdf: Sdf::Sphere {
            center: [0.0; 3],
            radius: 1.0,
        },
        alpha: 1.0,
        beta: 0.05,
        rainbow: true,
        feature: [1.0, 1.0, 1.0],
    };
    SdfField::fixed(&volume, &Device::Cpu).unwrap()
}

/// A unit sphere with a soft surface, and 64 rays from (0, 0, −4) spread over it.
fn scene() -> (SdfField, Rays) {
    let field = soft_unit_sphere();
    let (mut origins, mut directions) = (Vec::<f32>::new(), Vec::<f32>::new());
    for k in 0..64 {
        let (x, y) = ((k % 8) as f32 / 8.0 - 0.45, (k / 8) as f32 / 8.0 - 0.45);
        let norm = (x * x + y * y + 16.0).sqrt();
        origins.extend([0.0, 0.0, -4.0]);
        directions.extend([x / norm, y / norm, 4.0 / norm]);
    }
    let rays = Rays {
        origins: Tensor::from_vec(origins, (64, 3), &Device::Cpu).unwrap(),
        directions: Tensor::from_vec(directions, (64, 3), &Device::Cpu).unwrap(),
        camera_index: None,
    };
    (field, rays)
}

fn render(field: &SdfField, rays: &Rays, coarse: usize, fine: usize) -> RenderOutput {
    let stratified = StratifiedSampler::new(coarse, 2.0, 6.0).unwrap();
    let sampler: Box<dyn RaySampler> = match fine {
        0 => Box::new(stratified),
        n_fine => Box::new(CoarseToFineSampler {
            coarse: stratified,
            n_fine,
        }),
    };
    VolumeRenderer::new(1024, false)
        .unwrap()
        .render(field, &*sampler, rays, None)
        .unwrap()
}

fn mean_abs_diff(a: &Tensor, b: &Tensor) -> f32 {
    a.sub(b)
        .unwrap()
        .abs()
        .unwrap()
        .mean_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap()
}

#[test]
fn fine_samples_bring_the_render_closer_to_the_dense_one_than_as_many_stratified() {
    let (field, rays) = scene();
    let reference = render(&field, &rays, 4096, 0);
    let stratified = render(&field, &rays, 32, 0);
    let hierarchical = render(&field, &rays, 16, 16);
    assert_eq!(hierarchical.color.dims(), &[64, 3]);
    assert_eq!(hierarchical.samples.total, 64 * 32);
    assert_eq!(hierarchical.samples.evaluated, 64 * 48);
    let depth = |o: &RenderOutput| mean_abs_diff(&o.depth, &reference.depth);
    let colour = |o: &RenderOutput| mean_abs_diff(&o.color, &reference.color);
    assert!(
        depth(&hierarchical) < 0.9 * depth(&stratified),
        "depth error: hierarchical {} stratified {}",
        depth(&hierarchical),
        depth(&stratified)
    );
    assert!(
        colour(&hierarchical) < 0.9 * colour(&stratified),
        "colour error: hierarchical {} stratified {}",
        colour(&hierarchical),
        colour(&stratified)
    );
}

#[test]
fn fine_pass_trains_the_field_it_renders() {
    // Gradients reach the field's parameters through the fine pass, jittered as in
    // training.
    let (field, rays) = scene();
    let trainable = crate::sdf::SdfTrainable {
        center: true,
        ..Default::default()
    };
    let field = SdfField::new(&field.values().unwrap(), trainable, &Device::Cpu).unwrap();
    let sampler = CoarseToFineSampler {
        coarse: StratifiedSampler::new(8, 2.0, 6.0).unwrap(),
        n_fine: 8,
    };
    let mut rng = <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(4);
    let out = VolumeRenderer::new(1024, false)
        .unwrap()
        .render(&field, &sampler, &rays, Some(&mut rng))
        .unwrap();
    let grads = out.color.sum_all().unwrap().backward().unwrap();
    let (_, center) = &field.variables[0];
    let g = grads.get(center).expect("gradient of the centre");
    assert!(abs_sum(g) > 0.0);
}
