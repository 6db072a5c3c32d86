//! The seam every lens model implements, and the COLMAP camera models that name one.

use glam::{DVec2, DVec3};

use super::LensDistortion;

/// Newton stops when the residual `|distort(p) − target|` is below this (normalised units).
pub(crate) const RESIDUAL_TOLERANCE: f64 = 1e-14;
/// Newton gives up after this many steps, keeping the iterate with the smallest residual.
pub(crate) const MAX_NEWTON_STEPS: usize = 100;
/// Radii below this are treated as the optical axis (as COLMAP does with machine epsilon).
pub(crate) const AXIS_RADIUS: f64 = f64::EPSILON;

/// How one lens model moves points on the normalised image plane (OpenCV axes, `p = (X/Z,
/// Y/Z)`). Each model is a file of `crate::lens` and one line of its `lens_models!` list.
pub(crate) trait LensModel {
    /// The distorted normalised point of the undistorted normalised point `p`.
    fn distort(&self, p: DVec2) -> DVec2;

    /// The undistorted normalised point whose distortion is `distorted`, or `None` when no
    /// ray in front of the camera has it (a fisheye ray 90° or more from the axis).
    fn undistort(&self, distorted: DVec2) -> Option<DVec2>;

    /// The unit camera-space direction of the ray imaged at `distorted`; unlike
    /// [`LensModel::undistort`] it exists for rays at or beyond 90° from the axis too.
    fn undistorted_direction(&self, distorted: DVec2) -> DVec3;

    /// Whether the lens maps one ray to the distorted point `d`: undistortion converges
    /// (`distort(undistort(d))` within `tolerance` of `d`) and the distortion keeps its
    /// orientation there. The error says how it fails.
    fn check_invertible_at(&self, d: DVec2, tolerance: f64) -> Result<(), String>;

    /// Every coefficient, for finiteness checks.
    fn coefficients(&self) -> Vec<f64>;

    /// Whether the lens images angles rather than tangents (a fisheye), which allows a field
    /// of view of 180° and more.
    fn is_fisheye(&self) -> bool {
        false
    }
}

/// A COLMAP camera model (`cameras.txt`'s `MODEL` column): its name, its id in COLMAP's
/// binary files, its parameter list, and the lens its distortion parameters make.
#[derive(Debug)]
pub struct ColmapCameraModel {
    /// COLMAP's id of the model (`cameras.bin`; `src/colmap/sensor/models.h`).
    pub id: i32,
    /// COLMAP's name of the model, e.g. `OPENCV`.
    pub name: &'static str,
    /// The parameter names in COLMAP's order: the focal length (`f`, or `fx, fy`), the
    /// principal point `cx, cy`, then the distortion parameters.
    pub parameters: &'static [&'static str],
    /// The lens of the distortion parameters (those after `cx, cy`), as many as the list
    /// names.
    pub(crate) lens: fn(&[f64]) -> LensDistortion,
}

impl ColmapCameraModel {
    /// The model of a COLMAP name; an error naming the unknown model and the supported ones.
    pub fn from_name(name: &str) -> anyhow::Result<&'static Self> {
        let models = super::colmap_camera_models();
        models
            .iter()
            .find(|model| model.name == name)
            .copied()
            .ok_or_else(|| {
                let supported: Vec<_> = models.iter().map(|m| m.name).collect();
                anyhow::anyhow!(
                    "unknown COLMAP camera model `{name}` (supported: {})",
                    supported.join(", ")
                )
            })
    }

    /// Splits COLMAP's parameter list into focal lengths `[fx, fy]`, principal point
    /// `[cx, cy]` (pixels) and the lens distortion; an error naming the model when the
    /// parameter count is wrong.
    pub fn intrinsics(
        &self,
        params: &[f64],
    ) -> anyhow::Result<([f64; 2], [f64; 2], LensDistortion)> {
        let names = self.parameters;
        anyhow::ensure!(
            params.len() == names.len(),
            "COLMAP camera model {} takes {} parameters ({}), got {}",
            self.name,
            names.len(),
            names.join(", "),
            params.len()
        );
        // One focal length `f` or two, `fx, fy`; then `cx, cy`; then the lens's.
        let (focal, rest) = match names[0] {
            "f" => ([params[0], params[0]], &params[1..]),
            _ => ([params[0], params[1]], &params[2..]),
        };
        Ok((focal, [rest[0], rest[1]], (self.lens)(&rest[2..])))
    }
}
