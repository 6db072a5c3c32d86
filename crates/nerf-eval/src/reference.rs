//! A float64, one-ray-at-a-time recomputation of the homework maths for SDF volumes: the
//! independent yardstick that tests and `nerf bench` compare the tensor pipeline against.
//! It follows the homework literally (σ = −ln(1 − density)/Δ, cumulative product of
//! transmittance), with no clamping and no fused kernels.

use glam::DVec3;

use nerf_core::camera::Camera;
use nerf_core::sdf::{Sdf, SdfVolume};
use nerf_render::sampler::StratifiedSampler;

/// A shape in f64: a box by its centre and half side lengths, a sphere by its centre and
/// radius.
enum Shape {
    Box { c: DVec3, half: DVec3 },
    Sphere { c: DVec3, r: f64 },
}

impl Shape {
    fn of(sdf: &Sdf) -> Self {
        match *sdf {
            Sdf::Box {
                center,
                side_lengths,
            } => Shape::Box {
                c: DVec3::from_array(center.map(f64::from)),
                half: DVec3::from_array(side_lengths.map(|v| 0.5 * v as f64)),
            },
            Sdf::Sphere { center, radius } => Shape::Sphere {
                c: DVec3::from_array(center.map(f64::from)),
                r: radius as f64,
            },
        }
    }
}

/// Signed distance in f64.
pub(crate) fn signed_distance(sdf: &Sdf, p: DVec3) -> f64 {
    match Shape::of(sdf) {
        Shape::Box { c, half } => {
            let q = (p - c).abs() - half;
            q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
        }
        Shape::Sphere { c, r } => (p - c).length() - r,
    }
}

/// The volume's colour at `p`: `clamp(|p − center|, 0.02, 0.98) · feature` for a rainbow
/// volume, `feature` otherwise.
pub fn surface_color(volume: &SdfVolume, p: DVec3) -> [f64; 3] {
    let feature = volume.feature.map(f64::from);
    if volume.rainbow {
        let c = DVec3::from_array(volume.sdf.center().map(f64::from));
        let rgb = (p - c).abs().clamp(DVec3::splat(0.02), DVec3::splat(0.98));
        std::array::from_fn(|k| rgb[k] * feature[k])
    } else {
        feature
    }
}

/// Shortest chord through the solid that counts as a hit in [`analytic_hit`].
pub(crate) const MIN_CHORD: f64 = 1e-9;

/// Distance along the ray `origin + t·direction` (`direction` a unit vector) to the first
/// point of the surface with `t ≥ 0`, or `None` if the ray misses: the slab method for a box,
/// the quadratic for a sphere. A ray starting inside hits at `t = 0`. A ray that only touches
/// the solid (along an edge or a face, or tangent to the sphere: a chord shorter than
/// `MIN_CHORD`) crosses no volume, so volume rendering sees nothing there: a miss.
pub fn analytic_hit(sdf: &Sdf, origin: DVec3, direction: DVec3) -> Option<f64> {
    match Shape::of(sdf) {
        Shape::Box { c, half } => {
            let (mut t_near, mut t_far) = (0f64, f64::INFINITY);
            for k in 0..3 {
                let (o, d) = (origin[k] - c[k], direction[k]);
                if d == 0.0 {
                    // Parallel to this slab: inside it, or at best along a face (no volume).
                    if o.abs() >= half[k] {
                        return None;
                    }
                    continue;
                }
                let (t0, t1) = ((-half[k] - o) / d, (half[k] - o) / d);
                t_near = t_near.max(t0.min(t1));
                t_far = t_far.min(t0.max(t1));
            }
            (t_far - t_near > MIN_CHORD).then_some(t_near)
        }
        Shape::Sphere { c, r } => {
            let oc = origin - c;
            let b = oc.dot(direction);
            let disc = b * b - (oc.length_squared() - r.powi(2));
            if disc < 0.0 {
                return None;
            }
            let (t0, t1) = (-b - disc.sqrt(), -b + disc.sqrt());
            if t1 - t0.max(0.0) <= MIN_CHORD {
                None
            } else {
                Some(t0.max(0.0))
            }
        }
    }
}

/// The smallest signed distance to the surface along the segment `origin + t·direction`,
/// `t ∈ [0, t_max]`: how close a ray that misses comes to the surface. The distance to a
/// convex solid (box, sphere) is convex along a line, so a golden-section search finds it
/// (to about 1e-12 in t).
pub fn closest_approach(sdf: &Sdf, origin: DVec3, direction: DVec3, t_max: f64) -> f64 {
    let f = |t: f64| signed_distance(sdf, origin + direction * t);
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    let (mut a, mut b) = (0.0, t_max);
    while b - a > 1e-12 * t_max.max(1.0) {
        let (c, d) = (b - ratio * (b - a), a + ratio * (b - a));
        if f(c) < f(d) {
            b = d;
        } else {
            a = c;
        }
    }
    f(0.5 * (a + b)).min(f(0.0)).min(f(t_max))
}

/// Colour and depth of one ray, `([r, g, b], depth)`.
pub fn render_ray(
    volume: &SdfVolume,
    origin: DVec3,
    direction: DVec3,
    sampler: &StratifiedSampler,
) -> ([f64; 3], f64) {
    let z = sampler.depths();
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
        let rgb = surface_color(volume, p);
        for k in 0..3 {
            color[k] += w * rgb[k];
        }
        depth += w * zi;
    }
    (color, depth)
}

/// Every pixel of a `width × height` image: `(H·W·3)` colours and `(H·W)` depths, row-major.
pub fn render_image(
    volume: &SdfVolume,
    camera: &Camera,
    (width, height): (usize, usize),
    sampler: &StratifiedSampler,
) -> (Vec<f64>, Vec<f64>) {
    let mut colors = Vec::with_capacity(width * height * 3);
    let mut depths = Vec::with_capacity(width * height);
    for i in 0..width * height {
        let (o, d) = camera.pixel_ray(i % width, i / width, (width, height));
        let (c, z) = render_ray(volume, o, d, sampler);
        colors.extend(c);
        depths.push(z);
    }
    (colors, depths)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn analytic_hits_lie_on_the_surface_and_misses_stay_outside() {
        let shapes = [
            Sdf::Box {
                center: [0.1, -0.2, 0.3],
                side_lengths: [1.75, 1.0, 0.5],
            },
            Sdf::Sphere {
                center: [0.0, 0.5, 0.0],
                radius: 0.8,
            },
        ];
        let origin = DVec3::new(0.3, 0.4, -4.0);
        let (mut hits, mut misses) = (0, 0);
        for sdf in &shapes {
            for i in 0..400 {
                // Directions fanning out from the origin, some along the axis exactly.
                let (u, v) = ((i % 20) as f64 / 19.0 - 0.5, (i / 20) as f64 / 19.0 - 0.5);
                let d = DVec3::new(u * 0.6, v * 0.6, 1.0).normalize();
                match analytic_hit(sdf, origin, d) {
                    Some(t) => {
                        hits += 1;
                        assert!(signed_distance(sdf, origin + d * t).abs() < 1e-9);
                        // Nothing of the solid before the hit.
                        for k in 0..100 {
                            let s = signed_distance(sdf, origin + d * (t * k as f64 / 100.0));
                            assert!(s > -1e-9, "inside before the hit");
                        }
                    }
                    None => {
                        misses += 1;
                        for k in 0..2000 {
                            let s = signed_distance(sdf, origin + d * (k as f64 * 0.005));
                            assert!(s > 0.0, "a miss passes through the solid");
                        }
                    }
                }
            }
        }
        assert!(hits > 100 && misses > 100, "{hits} hits, {misses} misses");
        // Starting inside: hit at 0. Axis-parallel rays with zero components.
        assert_eq!(
            analytic_hit(&shapes[0], DVec3::new(0.1, -0.2, 0.3), DVec3::Z),
            Some(0.0)
        );
        let t = analytic_hit(&shapes[0], DVec3::new(0.1, -0.2, -4.0), DVec3::Z).unwrap();
        // The centre is an f32 (0.3 is 0.30000001 there).
        assert!((t - (4.0 + 0.3 - 0.25)).abs() < 1e-7);
        assert_eq!(
            analytic_hit(&shapes[0], DVec3::new(2.0, 0.0, -4.0), DVec3::Z),
            None
        );
        // Grazing exactly along an edge or a face: no chord, no hit.
        let unit_box = Sdf::Box {
            center: [0.0; 3],
            side_lengths: [2.0; 3],
        };
        let edge = DVec3::new(0.0, 1.0, -1.0) - DVec3::new(0.0, 0.0, -3.0);
        assert_eq!(
            analytic_hit(&unit_box, DVec3::new(0.0, 0.0, -3.0), edge.normalize()),
            None
        );
        assert_eq!(
            analytic_hit(&unit_box, DVec3::new(1.0, 0.5, -3.0), DVec3::Z),
            None
        );
        let sphere = Sdf::Sphere {
            center: [0.0; 3],
            radius: 1.0,
        };
        assert_eq!(
            analytic_hit(&sphere, DVec3::new(1.0, 0.0, -3.0), DVec3::Z),
            None
        );
        assert!(analytic_hit(&sphere, DVec3::new(0.999, 0.0, -3.0), DVec3::Z).is_some());
    }

    #[test]
    fn closest_approach_matches_a_fine_scan() {
        let b = Sdf::Box {
            center: [0.1, -0.2, 0.3],
            side_lengths: [1.75, 1.0, 0.5],
        };
        let o = DVec3::new(0.3, 0.4, -4.0);
        for i in 0..50 {
            let d = DVec3::new(0.4 - i as f64 * 0.016, 0.2, 1.0).normalize();
            let scan = (0..=200_000)
                .map(|k| signed_distance(&b, o + d * (k as f64 * 6.0 / 200_000.0)))
                .fold(f64::INFINITY, f64::min);
            let found = closest_approach(&b, o, d, 6.0);
            assert!(
                found <= scan + 1e-9 && found > scan - 1e-4,
                "{found} {scan}"
            );
        }
        // Exactly along an edge: zero.
        let unit = Sdf::Box {
            center: [0.0; 3],
            side_lengths: [2.0; 3],
        };
        let d = (DVec3::new(0.0, 1.0, -1.0) - DVec3::new(0.0, 0.0, -3.0)).normalize();
        assert!(closest_approach(&unit, DVec3::new(0.0, 0.0, -3.0), d, 5.0).abs() < 1e-9);
    }
}
