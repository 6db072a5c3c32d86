//! The camera seam: how a point of the homework's pixel grid becomes a ray.
//!
//! Every camera kind (a projection model, with or without lens distortion) implements
//! [`CameraModel`] in a file of its own, as COLMAP organises its camera models; rays
//! ([`crate::rays::Rays`]) and the renderer (`nerf::render_view`) take any of them.
//! The pinhole kind is pytorch3d's `PerspectiveCameras`, [`crate::camera::PerspectiveCamera`].

use glam::DVec3;

use crate::camera_error::CameraError;

/// A camera: its pose and how it images the world.
pub trait CameraModel: std::fmt::Debug + Send + Sync {
    /// The camera centre in world space.
    fn center(&self) -> DVec3;

    /// The world-space point imaged at the NDC point `(x, y)` (the homework's convention: +X
    /// left, +Y up, both in [-1, 1] across the image) at view depth `depth`.
    fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3;

    /// An error naming what is wrong when the camera cannot image anything (a non-finite or
    /// degenerate pose or intrinsics; see [`CameraError`]).
    fn validate(&self) -> Result<(), CameraError>;

    /// Origin and unit direction of the ray through the NDC point `(x, y)`: from the centre
    /// towards the point unprojected at depth 1.
    fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let origin = self.center();
        let target = self.unproject_ndc(x, y, 1.0);
        (origin, (target - origin).normalize())
    }

    /// Origin and unit direction of the ray through pixel `(column, row)` of a
    /// `width × height` image (row 0 the top). The default is the homework's pixel grid
    /// ([`crate::pixel_grid::homework_ndc`]: pixel centres reach the image's edges); a camera
    /// with pixel intrinsics overrides it with its own convention (COLMAP's: the centre of
    /// pixel `i` at `i + 0.5`).
    fn pixel_ray(&self, column: usize, row: usize, size: (usize, usize)) -> (DVec3, DVec3) {
        let [x, y] = crate::pixel_grid::homework_ndc(column, row, size);
        self.ray_through_ndc(x, y)
    }
}
