//! The field-of-view lens of Devernay and Faugeras ("Straight lines have to be straight",
//! 2001): COLMAP's `FOV` model, `fx, fy, cx, cy, omega`.
//!
//! A normalised point at radius `r` moves to radius `r_d = atan(2r·tan(ω/2)) / ω` along
//! the same direction; `ω` is the field of view of an ideal fisheye lens. The inverse is in
//! closed form, `r = tan(r_d·ω) / (2·tan(ω/2))`, for `r_d·ω < π/2`; beyond, no ray in front
//! of the camera is imaged.

use glam::{DVec2, DVec3};

use super::lens_model::{ColmapCameraModel, LensModel};
use super::LensDistortion;

/// Below this `|ω|` the lens is the identity, and below this `r` (or `r_d`) the ratio
/// `r_d / r` is its limit at the axis: both to within f64 rounding.
const SMALL: f64 = 1e-8;

/// The field-of-view lens with angle `omega` (radians).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldOfView {
    /// The field of view `ω` of the ideal fisheye lens, in radians.
    pub omega: f64,
}

impl FieldOfView {
    /// `2·tan(ω/2)`.
    fn two_tan_half(&self) -> f64 {
        2.0 * (0.5 * self.omega).tan()
    }
}

impl LensModel for FieldOfView {
    fn distort(&self, p: DVec2) -> DVec2 {
        if self.omega.abs() < SMALL {
            return p;
        }
        let r = p.length();
        let ratio = if r < SMALL {
            self.two_tan_half() / self.omega
        } else {
            (r * self.two_tan_half()).atan() / (r * self.omega)
        };
        p * ratio
    }

    fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        if self.omega.abs() < SMALL {
            return Some(distorted);
        }
        let r_d = distorted.length();
        if r_d * self.omega.abs() >= std::f64::consts::FRAC_PI_2 {
            return None;
        }
        let ratio = if r_d < SMALL {
            self.omega / self.two_tan_half()
        } else {
            (r_d * self.omega).tan() / (r_d * self.two_tan_half())
        };
        Some(distorted * ratio)
    }

    fn undistorted_direction(&self, distorted: DVec2) -> DVec3 {
        match self.undistort(distorted) {
            Some(p) => p.extend(1.0).normalize(),
            // At or beyond the lens's 90°: the direction along the image plane.
            None => distorted.normalize().extend(0.0),
        }
    }

    fn check_invertible_at(&self, d: DVec2, _tolerance: f64) -> Result<(), String> {
        if !(0.0..std::f64::consts::PI).contains(&self.omega) {
            return Err(format!(
                "the FOV lens's omega {} is not in [0, π)",
                self.omega
            ));
        }
        match self.undistort(d) {
            Some(_) => Ok(()),
            None => Err(format!(
                "the FOV lens (omega {}) images no ray at ({:.4}, {:.4})",
                self.omega, d.x, d.y
            )),
        }
    }

    fn coefficients(&self) -> Vec<f64> {
        vec![self.omega]
    }
}

/// COLMAP's `FOV` model; `p` holds the parameters after `cx, cy`.
pub(crate) const COLMAP_MODELS: &[ColmapCameraModel] = &[ColmapCameraModel {
    id: 7,
    name: "FOV",
    parameters: &["fx", "fy", "cx", "cy", "omega"],
    lens: |p| LensDistortion::FieldOfView(FieldOfView { omega: p[0] }),
}];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radius_follows_atan_and_tan_by_hand() {
        // ω = 0.9, r = 0.5: r_d = atan(2·0.5·tan(0.45)) / 0.9 = atan(0.48305) / 0.9.
        let lens = FieldOfView { omega: 0.9 };
        let p = DVec2::new(0.3, 0.4);
        let r_d = (0.45f64.tan()).atan() / 0.9;
        assert!((lens.distort(p).length() - r_d).abs() < 1e-15);
        assert!((lens.distort(p).normalize() - p.normalize()).length() < 1e-15);
        let back = lens.undistort(lens.distort(p)).unwrap();
        assert!((back - p).length() < 1e-14, "{back}");
    }

    #[test]
    fn the_axis_and_a_zero_omega_are_continuous() {
        let lens = FieldOfView { omega: 0.9 };
        let near = DVec2::new(1e-9, 0.0);
        let at_limit = lens.distort(near).x / near.x;
        let beside = lens.distort(DVec2::new(1e-5, 0.0)).x / 1e-5;
        assert!((at_limit - beside).abs() < 1e-9);
        let flat = FieldOfView { omega: 0.0 };
        assert_eq!(flat.distort(DVec2::new(0.3, 0.4)), DVec2::new(0.3, 0.4));
    }

    #[test]
    fn beyond_ninety_degrees_there_is_no_ray_and_the_check_says_so() {
        let lens = FieldOfView { omega: 1.0 };
        let far = DVec2::new(1.6, 0.0);
        assert!(lens.undistort(far).is_none());
        assert_eq!(lens.undistorted_direction(far), DVec3::X);
        assert!(lens.check_invertible_at(far, 1e-9).is_err());
        assert!(lens.check_invertible_at(DVec2::new(0.5, 0.2), 1e-9).is_ok());
    }
}
