//! The ideal pinhole: no lens distortion (COLMAP's `SIMPLE_PINHOLE` and `PINHOLE`).

use glam::{DVec2, DVec3};

use super::lens_model::{ColmapCameraModel, LensModel};
use super::LensDistortion;

/// An ideal pinhole: `distort(p) = p`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NoDistortion;

impl LensModel for NoDistortion {
    fn distort(&self, p: DVec2) -> DVec2 {
        p
    }

    fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        Some(distorted)
    }

    fn undistorted_direction(&self, distorted: DVec2) -> DVec3 {
        distorted.extend(1.0).normalize()
    }

    fn check_invertible_at(&self, _d: DVec2, _tolerance: f64) -> Result<(), String> {
        Ok(())
    }

    fn coefficients(&self) -> Vec<f64> {
        Vec::new()
    }
}

/// COLMAP's models without distortion.
pub(crate) const COLMAP_MODELS: &[ColmapCameraModel] = &[
    ColmapCameraModel {
        id: 0,
        name: "SIMPLE_PINHOLE",
        parameters: &["f", "cx", "cy"],
        lens: |_| LensDistortion::None(NoDistortion),
    },
    ColmapCameraModel {
        id: 1,
        name: "PINHOLE",
        parameters: &["fx", "fy", "cx", "cy"],
        lens: |_| LensDistortion::None(NoDistortion),
    },
];
