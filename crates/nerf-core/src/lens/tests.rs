//! The lens models against each other, finite differences and COLMAP by hand.

use glam::{DVec2, DVec3};

use super::*;

/// Realistic lenses of each family.
fn lenses() -> Vec<(&'static str, LensDistortion)> {
    vec![
        ("none", LensDistortion::NONE),
        (
            "opencv",
            LensDistortion::polynomial([-0.1, 0.02, 0.0, 0.0], [1e-3, -5e-4]),
        ),
        (
            "nerfstudio opencv (k3, k4)",
            LensDistortion::polynomial([-0.12, 0.03, -0.004, 0.0005], [8e-4, 6e-4]),
        ),
        (
            "full opencv",
            LensDistortion::RadialTangential(RadialTangential {
                numerator: [-0.1, 0.02, 0.003, 0.0],
                denominator: [0.01, -0.005, 0.001],
                tangential: [1e-3, -5e-4],
            }),
        ),
        (
            "fisheye",
            LensDistortion::Fisheye(Fisheye {
                k: [0.05, -0.01, 0.002, -0.0005],
            }),
        ),
    ]
}

fn sample_points() -> Vec<DVec2> {
    let mut points = Vec::new();
    for i in -8..=8 {
        for j in -6..=6 {
            points.push(DVec2::new(i as f64 * 0.1, j as f64 * 0.1 + 0.013));
        }
    }
    points.push(DVec2::ZERO);
    points
}

#[test]
fn undistort_inverts_distort() {
    for (name, lens) in lenses() {
        let mut worst: f64 = 0.0;
        for p in sample_points() {
            let back = lens.undistort(lens.distort(p)).unwrap();
            worst = worst.max((back - p).length());
        }
        eprintln!("{name}: worst |undistort(distort(p)) − p| = {worst:.3e}");
        assert!(worst < 1e-9, "{name}: {worst}");
    }
}

#[test]
fn analytic_jacobian_matches_finite_differences() {
    let LensDistortion::RadialTangential(lens) = lenses()[3].1 else {
        unreachable!("lenses()[3] is the full OpenCV lens")
    };
    let h = 1e-6;
    for p in [DVec2::new(0.3, -0.4), DVec2::new(-0.7, 0.2)] {
        let j = lens.with_jacobian(p).jacobian;
        for (axis, step) in [DVec2::new(h, 0.0), DVec2::new(0.0, h)].iter().enumerate() {
            let numeric = (lens.distort(p + *step) - lens.distort(p - *step)) / (2.0 * h);
            assert!((numeric.x - j[0][axis]).abs() < 1e-8, "{p} {axis}");
            assert!((numeric.y - j[1][axis]).abs() < 1e-8, "{p} {axis}");
        }
    }
}

#[test]
fn fisheye_directions_reach_beyond_ninety_degrees() {
    let lens = LensDistortion::Fisheye(Fisheye { k: [0.0; 4] });
    // Equidistant: a distorted radius of 2 is an angle of 2 rad (> 90°) from the axis.
    let d = lens.undistorted_direction(DVec2::new(0.0, 2.0));
    assert!((d - DVec3::new(0.0, 2f64.sin(), 2f64.cos())).length() < 1e-12);
    assert!(lens.undistort(DVec2::new(0.0, 2.0)).is_none());
}

#[test]
fn radial_tangential_matches_colmap_opencv_by_hand() {
    // COLMAP OPENCV with k1 = -0.1, k2 = 0.02, p1 = 1e-3, p2 = -5e-4 at (0.3, -0.2):
    // r² = 0.13, radial = 1 − 0.013 + 0.000338 = 0.987338,
    // x_d = 0.3·0.987338 + 2·1e-3·(−0.06) − 5e-4·(0.13 + 0.18) = 0.2959264,
    // y_d = −0.2·0.987338 + 2·(−5e-4)·(−0.06) + 1e-3·(0.13 + 0.08) = −0.1971976.
    let lens = lenses()[1].1;
    let d = lens.distort(DVec2::new(0.3, -0.2));
    assert!(
        (d - DVec2::new(0.2959264, -0.1971976)).length() < 1e-14,
        "{d}"
    );
}
