//! Numerical tests of the whole pipeline against values derived independently: analytic
//! ray–box intersections, a float64 re-implementation of the homework maths, and invariances.

use candle_core::{Device, Tensor};
use glam::DVec3;
use nerf::config::Config;
use nerf::core::camera::{surround_cameras, PerspectiveCamera};
use nerf::core::rays::{pixel_grid_values, ray_through_ndc, Rays};
use nerf::core::volume::{deltas, weights};
use nerf::render::field::Field;
use nerf::render::renderer::VolumeRenderer;
use nerf::render::sampler::StratifiedSampler;

fn box_config(overrides: &[&str]) -> Config {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Config::load("box", &o).unwrap()
}

fn render(
    field: &dyn Field,
    cam: &PerspectiveCamera,
    w: usize,
    h: usize,
    sampler: &StratifiedSampler,
    chunk: usize,
) -> (Vec<f32>, Vec<f32>) {
    let rays = Rays::for_image(&nerf::Camera::from(*cam), w, h, &Device::Cpu).unwrap();
    let out = VolumeRenderer::new(chunk, false)
        .unwrap()
        .render(field, sampler, &rays, None)
        .unwrap();
    assert_eq!(out.color.dims(), &[w * h, 3]);
    assert_eq!(out.depth.dims(), &[w * h, 1]);
    assert_eq!(out.opacity.dims(), &[w * h, 1]);
    (
        out.color.flatten_all().unwrap().to_vec1().unwrap(),
        out.depth.flatten_all().unwrap().to_vec1().unwrap(),
    )
}

/// Slab-method intersection of a ray with an axis-aligned box: `(t_enter, t_exit)`.
fn ray_box(o: DVec3, d: DVec3, center: DVec3, half: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for k in 0..3 {
        let (lo, hi) = (center[k] - half[k], center[k] + half[k]);
        if d[k] == 0.0 {
            if o[k] < lo || o[k] > hi {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo - o[k]) / d[k], (hi - o[k]) / d[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 <= t1 && t1 > 0.0).then_some((t0, t1))
}

#[test]
fn hard_box_depth_matches_analytic_intersection() {
    let config = box_config(&[
        "implicit_function.beta.val=1e-4",
        "implicit_function.feature.rainbow=False",
    ]);
    let field = config.sdf_field(&Device::Cpu).unwrap();
    let sampler = config.stratified_sampler().unwrap();
    let step = (sampler.max_depth - sampler.min_depth) / (sampler.n_pts_per_ray - 1) as f64;
    let (w, h) = (48, 40);
    let half = DVec3::splat(1.75 / 2.0);
    let mut checked = 0;
    for cam in surround_cameras(3.0, 20, DVec3::Y, 1.0).iter().step_by(3) {
        let (_, depth) = render(&field, cam, w, h, &sampler, 32768);
        for (i, [x, y]) in pixel_grid_values(w, h).into_iter().enumerate() {
            let (o, d) = ray_through_ndc(&nerf::Camera::from(*cam), x, y);
            match ray_box(o, d, DVec3::ZERO, half) {
                // Rays that cross the box squarely (not grazing an edge).
                Some((t0, t1)) if t1 - t0 > 3.0 * step => {
                    let err = depth[i] as f64 - t0;
                    assert!(
                        err.abs() <= step,
                        "pixel {i}: depth {} vs analytic {t0} (step {step})",
                        depth[i]
                    );
                    checked += 1;
                }
                // Rays that miss by more than a sample step see (almost) nothing.
                None => {
                    let near_miss = ray_box(o, d, DVec3::ZERO, half + step).is_some();
                    if !near_miss {
                        assert!(
                            depth[i].abs() < 1e-3,
                            "pixel {i}: depth {} for a miss",
                            depth[i]
                        );
                    }
                }
                _ => {}
            }
        }
    }
    assert!(checked > 500, "only {checked} rays checked");
}

#[test]
fn box_render_agrees_with_float64_recomputation() {
    let config = box_config(&[]);
    let field = config.sdf_field(&Device::Cpu).unwrap();
    let volume = &config.sdf_volume().unwrap();
    let sampler = config.stratified_sampler().unwrap();
    let (w, h) = (40, 30);
    let mut max_color: f64 = 0.0;
    let mut max_depth: f64 = 0.0;
    for cam in surround_cameras(3.0, 20, DVec3::Y, 1.0).iter().step_by(4) {
        let (color, depth) = render(&field, cam, w, h, &sampler, 500);
        for (i, [x, y]) in pixel_grid_values(w, h).into_iter().enumerate() {
            let (o, d) = ray_through_ndc(&nerf::Camera::from(*cam), x, y);
            let (rc, rd) = nerf::eval::reference::render_ray(volume, o, d, &sampler);
            for k in 0..3 {
                max_color = max_color.max((color[3 * i + k] as f64 - rc[k]).abs());
            }
            max_depth = max_depth.max((depth[i] as f64 - rd).abs());
        }
    }
    eprintln!("f32 vs f64: max colour error {max_color:.2e}, max depth error {max_depth:.2e}");
    assert!(max_color < 1e-4, "colour error {max_color}");
    assert!(max_depth < 1e-3, "depth error {max_depth}");
}

#[test]
fn chunk_size_does_not_change_the_image() {
    let config = box_config(&[]);
    let field = config.sdf_field(&Device::Cpu).unwrap();
    let sampler = config.stratified_sampler().unwrap();
    let cam = config.surround_cameras()[2];
    let (w, h) = (64, 48);
    let big = render(&field, &cam, w, h, &sampler, 32768);
    for chunk in [1000, 7, 3072] {
        assert_eq!(
            render(&field, &cam, w, h, &sampler, chunk),
            big,
            "chunk {chunk}"
        );
    }
}

#[test]
fn weights_are_bounded_for_random_densities() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    for (n, s) in [(1, 1), (5, 2), (33, 17), (128, 64)] {
        let sigma: Vec<f32> = (0..n * s)
            .map(|_| rng.random::<f32>().powi(4) * 1e3)
            .collect();
        let mut lengths = Vec::new();
        for _ in 0..n {
            let mut t = rng.random::<f32>();
            for _ in 0..s {
                t += rng.random::<f32>() * 0.3;
                lengths.push(t);
            }
        }
        let l = Tensor::from_vec(lengths, (n, s, 1), &Device::Cpu).unwrap();
        let sg = Tensor::from_vec(sigma, (n, s, 1), &Device::Cpu).unwrap();
        let w = weights(&sg, &deltas(&l).unwrap()).unwrap();
        assert_eq!(w.dims(), &[n, s, 1]);
        for ray in w.squeeze(2).unwrap().to_vec2::<f32>().unwrap() {
            assert!(ray.iter().all(|v| (0.0..=1.0).contains(v)));
            assert!(ray.iter().sum::<f32>() <= 1.0 + 1e-6);
        }
    }
}

#[test]
fn sphere_and_non_square_images_work_through_config() {
    let config = box_config(&[
        "implicit_function.sdf.type=sphere",
        "implicit_function.sdf.radius.val=1.0",
        "data.image_size=[20,15]",
        "sampler.n_pts_per_ray=32",
    ]);
    let field = config.sdf_field(&Device::Cpu).unwrap();
    let sampler = config.stratified_sampler().unwrap();
    let cam = config.surround_cameras()[0];
    let (_, depth) = render(&field, &cam, 20, 15, &sampler, 100);
    // The central ray hits the unit sphere at distance 3 − 1 = 2 from a camera at radius 3.
    // The image has an odd height but even width, so look at the two central pixels.
    let centre = 7 * 20 + 9;
    assert!((depth[centre] - 2.0).abs() < 0.2, "depth {}", depth[centre]);
    // Corners miss the sphere.
    assert!(depth[0] < 1e-3);
}
