//! A float64, one-ray-at-a-time recomputation of the homework maths for SDF volumes: the
//! independent yardstick that tests and `nerf bench` compare the tensor pipeline against.
//! It follows the homework literally (σ = −ln(1 − density)/Δ, cumulative product of
//! transmittance), with no clamping and no fused kernels.

use glam::DVec3;

use crate::camera::PerspectiveCamera;
use crate::rays::{pixel_grid_values, ray_through_ndc};
use crate::sampler::StratifiedSampler;
use crate::sdf::{Sdf, SdfVolume};

/// Signed distance in f64.
pub fn signed_distance(sdf: &Sdf, p: DVec3) -> f64 {
    match *sdf {
        Sdf::Box {
            center,
            side_lengths,
        } => {
            let c = DVec3::from_array(center.map(f64::from));
            let half = DVec3::from_array(side_lengths.map(|v| 0.5 * v as f64));
            let q = (p - c).abs() - half;
            q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
        }
        Sdf::Sphere { center, radius } => {
            (p - DVec3::from_array(center.map(f64::from))).length() - radius as f64
        }
    }
}

/// Colour and depth of one ray, `([r, g, b], depth)`.
pub fn render_ray(
    volume: &SdfVolume,
    origin: DVec3,
    direction: DVec3,
    sampler: &StratifiedSampler,
) -> ([f64; 3], f64) {
    let z = sampler.depths();
    let c = DVec3::from_array(volume.sdf.center().map(f64::from));
    let (mut color, mut depth, mut transmittance) = ([0f64; 3], 0f64, 1f64);
    for (i, &zi) in z.iter().enumerate() {
        let p = origin + direction * zi;
        let s = signed_distance(&volume.sdf, p);
        let (alpha, beta) = (volume.alpha, volume.beta);
        let density = alpha
            * if s > 0.0 {
                0.5 * (-s / beta).exp()
            } else {
                1.0 - 0.5 * (s / beta).exp()
            };
        let delta = if i + 1 < z.len() { z[i + 1] - zi } else { 1e10 };
        let sigma = -(1.0 - density).ln() / delta;
        // The renderer's limit: zero spacing has zero optical depth, whatever σ is.
        let a = if delta == 0.0 {
            1.0
        } else {
            (-sigma * delta).exp()
        };
        let w = transmittance * (1.0 - a);
        transmittance *= a;
        let rgb = if volume.rainbow {
            (p - c)
                .abs()
                .clamp(DVec3::splat(0.02), DVec3::splat(0.98))
                .to_array()
        } else {
            [1.0; 3]
        };
        for k in 0..3 {
            color[k] += w * rgb[k] * volume.feature[k] as f64;
        }
        depth += w * zi;
    }
    (color, depth)
}

/// Every pixel of a `width × height` image: `(H·W·3)` colours and `(H·W)` depths, row-major.
pub fn render_image(
    volume: &SdfVolume,
    camera: &PerspectiveCamera,
    (width, height): (usize, usize),
    sampler: &StratifiedSampler,
) -> (Vec<f64>, Vec<f64>) {
    let mut colors = Vec::with_capacity(width * height * 3);
    let mut depths = Vec::with_capacity(width * height);
    for [x, y] in pixel_grid_values(width, height) {
        let (o, d) = ray_through_ndc(camera, x, y);
        let (c, z) = render_ray(volume, o, d, sampler);
        colors.extend(c);
        depths.push(z);
    }
    (colors, depths)
}
