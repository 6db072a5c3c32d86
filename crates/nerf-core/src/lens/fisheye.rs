//! The equidistant fisheye with a polynomial in the angle (Kannala–Brandt, OpenCV's
//! fisheye): COLMAP's and nerfstudio's `OPENCV_FISHEYE`.
//!
//! With `θ = atan(r)`, `θ_d = θ(1 + k₁θ² + k₂θ⁴ + k₃θ⁶ + k₄θ⁸)` and `p_d = p · θ_d / r`.
//! Undistortion solves `θ_d(θ) = |p_d|` by Newton's method (the distortion is radial).

use glam::{DVec2, DVec3};

use super::lens_model::{
    ColmapCameraModel, LensModel, AXIS_RADIUS, MAX_NEWTON_STEPS, RESIDUAL_TOLERANCE,
};
use super::LensDistortion;
use crate::term::short_number;

/// The equidistant fisheye with a polynomial in the angle `θ` from the optical axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fisheye {
    /// `[k₁, k₂, k₃, k₄]`, the coefficients of `θ², θ⁴, θ⁶, θ⁸`.
    pub k: [f64; 4],
}

impl Fisheye {
    /// `θ_d = θ(1 + k₁θ² + k₂θ⁴ + k₃θ⁶ + k₄θ⁸)`.
    fn theta_d(&self, theta: f64) -> f64 {
        let [k1, k2, k3, k4] = self.k;
        let t2 = theta * theta;
        theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    }

    /// `dθ_d/dθ`.
    fn slope(&self, theta: f64) -> f64 {
        let [k1, k2, k3, k4] = self.k;
        let t2 = theta * theta;
        1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    }

    /// The angle `θ ∈ [0, π)` with `θ_d(θ) = rho`, by Newton from `θ = rho`; the iterate
    /// with the smallest residual.
    fn solve_theta(&self, rho: f64) -> f64 {
        let mut theta = rho.min(std::f64::consts::PI * 0.999);
        let mut best = (f64::INFINITY, theta);
        for _ in 0..MAX_NEWTON_STEPS {
            let residual = self.theta_d(theta) - rho;
            if !residual.is_finite() {
                break;
            }
            if residual.abs() < best.0 {
                best = (residual.abs(), theta);
            }
            if residual.abs() <= RESIDUAL_TOLERANCE {
                break;
            }
            let slope = self.slope(theta);
            if slope.abs() < 1e-300 {
                break;
            }
            theta = (theta - residual / slope).clamp(0.0, std::f64::consts::PI * 0.999);
        }
        best.1
    }
}

impl LensModel for Fisheye {
    fn distort(&self, p: DVec2) -> DVec2 {
        let r = p.length();
        if r <= AXIS_RADIUS {
            return p;
        }
        let theta = r.atan();
        p * (self.theta_d(theta) / r)
    }

    fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        let direction = self.undistorted_direction(distorted);
        (direction.z > 0.0).then(|| DVec2::new(direction.x, direction.y) / direction.z)
    }

    fn undistorted_direction(&self, distorted: DVec2) -> DVec3 {
        let rho = distorted.length();
        if rho <= AXIS_RADIUS {
            return distorted.extend(1.0).normalize();
        }
        let theta = self.solve_theta(rho);
        let radial = distorted / rho * theta.sin();
        radial.extend(theta.cos())
    }

    fn check_invertible_at(&self, d: DVec2, tolerance: f64) -> Result<(), String> {
        let rho = d.length();
        let theta = self.solve_theta(rho);
        let residual = (self.theta_d(theta) - rho).abs();
        if residual.is_nan() || residual > tolerance {
            return Err(format!(
                "undistorting the fisheye radius {rho:.4} does not converge (residual {})",
                short_number(residual)
            ));
        }
        let slope = self.slope(theta);
        if slope.is_nan() || slope <= 0.0 {
            return Err(format!(
                "the fisheye's θ_d stops rising at θ = {:.1}°",
                theta.to_degrees()
            ));
        }
        Ok(())
    }

    fn coefficients(&self) -> Vec<f64> {
        self.k.to_vec()
    }

    fn is_fisheye(&self) -> bool {
        true
    }
}

/// COLMAP's fisheye model; `p` holds the parameters after `cx, cy`.
pub(crate) const COLMAP_MODELS: &[ColmapCameraModel] = &[ColmapCameraModel {
    id: 5,
    name: "OPENCV_FISHEYE",
    parameters: &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"],
    lens: |p| LensDistortion::Fisheye(Fisheye {
        k: [p[0], p[1], p[2], p[3]],
    }),
}];
