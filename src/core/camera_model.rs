//! The camera seam: how a point of the homework's pixel grid becomes a ray.
//!
//! Every camera kind (a projection model, with or without lens distortion) implements
//! [`CameraModel`] in a file of its own, as COLMAP organises its camera models; rays
//! ([`crate::core::rays::Rays`]) and the renderer ([`crate::render_view`]) take any of them.
//! The pinhole kind is pytorch3d's `PerspectiveCameras`, [`crate::core::camera::PerspectiveCamera`].

use anyhow::Result;
use glam::DVec3;

/// A camera: its pose and how it images the world.
pub trait CameraModel: std::fmt::Debug + Send + Sync {
    /// The camera centre in world space.
    fn center(&self) -> DVec3;

    /// The world-space point imaged at the NDC point `(x, y)` (the homework's convention: +X
    /// left, +Y up, both in [-1, 1] across the image) at view depth `depth`.
    fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3;

    /// An error naming what is wrong when the camera cannot image anything (a non-finite or
    /// degenerate pose or intrinsics).
    fn validate(&self) -> Result<()>;

    /// Origin and unit direction of the ray through the NDC point `(x, y)`: from the centre
    /// towards the point unprojected at depth 1.
    fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let origin = self.center();
        let target = self.unproject_ndc(x, y, 1.0);
        (origin, (target - origin).normalize())
    }

    /// Origin and unit direction of the ray through pixel `(column, row)` of a
    /// `width × height` image (row 0 the top). The default is the homework's pixel grid
    /// ([`crate::core::rays::homework_ndc`]: pixel centres reach the image's edges); a camera
    /// with pixel intrinsics overrides it with its own convention (COLMAP's: the centre of
    /// pixel `i` at `i + 0.5`).
    fn pixel_ray(&self, column: usize, row: usize, size: (usize, usize)) -> (DVec3, DVec3) {
        let [x, y] = crate::core::rays::homework_ndc(column, row, size);
        self.ray_through_ndc(x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::camera::surround_cameras;
    use crate::core::rays::Rays;
    use candle_core::Device;

    /// An orthographic camera looking down −z from z = 5, imaging a 2×2 square: a kind whose
    /// rays do not share an origin, so it overrides the default ray.
    #[derive(Debug)]
    struct Orthographic;

    impl CameraModel for Orthographic {
        fn center(&self) -> DVec3 {
            DVec3::new(0.0, 0.0, 5.0)
        }
        fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3 {
            // +X left in NDC: world x = −x for a camera looking down −z with +y up.
            DVec3::new(-x, y, 5.0 - depth)
        }
        fn validate(&self) -> Result<()> {
            Ok(())
        }
        fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
            (self.unproject_ndc(x, y, 0.0), DVec3::new(0.0, 0.0, -1.0))
        }
    }

    #[test]
    fn rays_come_from_any_camera_kind() {
        let rays = Rays::for_image(&Orthographic, 3, 2, &Device::Cpu).unwrap();
        let origins = rays.origins.to_vec2::<f32>().unwrap();
        let directions = rays.directions.to_vec2::<f32>().unwrap();
        // First pixel: top-left of the image, NDC (+1, +1) → world (−1, 1).
        assert_eq!(origins[0], [-1.0, 1.0, 5.0]);
        assert_eq!(origins[5], [1.0, -1.0, 5.0]);
        assert!(directions.iter().all(|d| *d == [0.0, 0.0, -1.0]));
    }

    #[test]
    fn the_pinhole_kind_is_pytorch3d_unprojection() {
        let camera = surround_cameras(4.0, 3, DVec3::Y, 1.5)[1];
        let (o, d) = CameraModel::ray_through_ndc(&camera, 0.3, -0.6);
        assert!((o - camera.center()).length() < 1e-12);
        let target = camera.unproject_ndc(0.3, -0.6, 1.0);
        assert!((d - (target - o).normalize()).length() < 1e-12);
    }
}
