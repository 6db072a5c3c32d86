//! The pinhole camera of the homework, in pytorch3d's conventions ([`PerspectiveCamera`]),
//! and pytorch3d's `look_at_view_transform`.
//!
//! * World → view is the row-vector transform `X_view = X_world · R + T` (pytorch3d
//!   `PerspectiveCameras`), so the camera centre is `C = −T · Rᵀ`.
//! * View space and NDC: +X left, +Y up, +Z forward (into the scene).
//! * Projection in NDC: `x_ndc = f_x · X / Z + p_x`, `y_ndc = f_y · Y / Z + p_y`.
//!
//! Camera maths is done in `f64` with glam; tensors handed to the renderer are `f32`.

use glam::{DMat3, DVec3};

use super::{CameraError, Projection};

/// A pinhole camera with pytorch3d `PerspectiveCameras` parameters (NDC focal length and
/// principal point).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerspectiveCamera {
    /// pytorch3d `R`, indexed `[row][column]`: `X_view = X_world · R + T` for row vectors.
    pub r: [[f64; 3]; 3],
    /// pytorch3d `T`.
    pub t: [f64; 3],
    /// NDC focal length `(f_x, f_y)`.
    pub focal: [f64; 2],
    /// NDC principal point `(p_x, p_y)`.
    pub principal_point: [f64; 2],
}

impl PerspectiveCamera {
    /// A camera from pytorch3d `R`, `T`, a single NDC focal length and a zero principal point.
    pub fn new(r: [[f64; 3]; 3], t: [f64; 3], focal: f64) -> Self {
        Self {
            r,
            t,
            focal: [focal, focal],
            principal_point: [0.0, 0.0],
        }
    }

    /// Rejects cameras with non-finite entries ([`CameraError::NotFinite`]) or a zero focal
    /// length ([`CameraError::FocalLength`]), naming the culprit.
    pub fn validate(&self) -> Result<(), CameraError> {
        let all = self
            .r
            .iter()
            .flatten()
            .chain(self.t.iter())
            .chain(self.focal.iter())
            .chain(self.principal_point.iter());
        if all.clone().any(|v| !v.is_finite()) {
            return Err(CameraError::NotFinite {
                values: "R, T, focal length or principal point",
            });
        }
        if self.focal.contains(&0.0) {
            return Err(CameraError::FocalLength {
                focal: self.focal,
                in_pixels: false,
            });
        }
        Ok(())
    }

    /// `R` as a glam matrix acting on column vectors, i.e. the matrix `Rᵀ` with
    /// `X_view = Rᵀ X_world + T`.
    fn world_to_view_rotation(&self) -> DMat3 {
        // from_cols_array_2d takes each inner array as a column, so row i of R becomes
        // column i, which is Rᵀ.
        DMat3::from_cols_array_2d(&self.r)
    }

    fn translation(&self) -> DVec3 {
        DVec3::from_array(self.t)
    }

    /// The camera centre in world space, `C = −T · Rᵀ`.
    pub fn center(&self) -> DVec3 {
        -(self.world_to_view_rotation().transpose() * self.translation())
    }

    /// World point → view point (`X·R + T`).
    pub(crate) fn world_to_view(&self, p: DVec3) -> DVec3 {
        self.world_to_view_rotation() * p + self.translation()
    }

    /// View point → world point (`(X − T)·Rᵀ`).
    pub(crate) fn view_to_world(&self, p: DVec3) -> DVec3 {
        self.world_to_view_rotation().transpose() * (p - self.translation())
    }

    /// World point → `(x_ndc, y_ndc, Z_view)`.
    pub fn project(&self, p: DVec3) -> DVec3 {
        let v = self.world_to_view(p);
        DVec3::new(
            self.focal[0] * v.x / v.z + self.principal_point[0],
            self.focal[1] * v.y / v.z + self.principal_point[1],
            v.z,
        )
    }

    /// Unprojects the NDC point `(x, y)` at view depth `depth` to world space, as pytorch3d's
    /// `unproject_points(xy_depth, world_coordinates=True, from_ndc=True)`.
    pub(crate) fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3 {
        let view = DVec3::new(
            (x - self.principal_point[0]) / self.focal[0] * depth,
            (y - self.principal_point[1]) / self.focal[1] * depth,
            depth,
        );
        self.view_to_world(view)
    }
}

impl Projection for PerspectiveCamera {
    fn center(&self) -> DVec3 {
        PerspectiveCamera::center(self)
    }

    fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3 {
        PerspectiveCamera::unproject_ndc(self, x, y, depth)
    }

    fn validate(&self) -> Result<(), CameraError> {
        PerspectiveCamera::validate(self)
    }

    fn ndc_focal(&self) -> [f64; 2] {
        self.focal
    }

    /// pytorch3d: `X_view = X_world · R`, so `R`'s columns are the view axes (x left, y up,
    /// z forward) in world space.
    fn viewing_axes(&self) -> (DVec3, DVec3) {
        let column = |j: usize| DVec3::new(self.r[0][j], self.r[1][j], self.r[2][j]);
        (column(2).normalize(), column(1).normalize())
    }
}

/// pytorch3d `look_at_rotation`: the rotation `R` (indexed `[row][col]`) whose columns are the
/// camera's x, y and z axes in world space.
pub fn look_at_rotation(eye: DVec3, at: DVec3, up: DVec3) -> [[f64; 3]; 3] {
    // pytorch3d normalises with eps = 1e-5 (norm clamped from below).
    let normalize = |v: DVec3| v / v.length().max(1e-5);
    let z_axis = normalize(at - eye);
    let mut x_axis = normalize(up.cross(z_axis));
    let y_axis = normalize(z_axis.cross(x_axis));
    // pytorch3d: if x is (close to) zero, up is parallel to the viewing direction; replace it.
    if x_axis.to_array().iter().all(|v| v.abs() <= 5e-3) {
        x_axis = normalize(y_axis.cross(z_axis));
    }
    // R has the axes as columns: R[i][j] = axis_j[i].
    let mut r = [[0.0; 3]; 3];
    for (j, axis) in [x_axis, y_axis, z_axis].iter().enumerate() {
        for (i, row) in r.iter_mut().enumerate() {
            row[j] = axis[i];
        }
    }
    r
}

/// pytorch3d `look_at_view_transform(eye=..., at=..., up=...)`: returns `(R, T)` with
/// `T = −Rᵀ·eye` (column-vector form).
pub fn look_at_view_transform(eye: DVec3, at: DVec3, up: DVec3) -> ([[f64; 3]; 3], [f64; 3]) {
    let r = look_at_rotation(eye, at, up);
    // Rᵀ as a glam matrix is from_cols_array_2d(r) (see world_to_view_rotation).
    let t = -(DMat3::from_cols_array_2d(&r) * eye);
    (r, t.to_array())
}

/// pytorch3d `camera_position_from_spherical_angles(dist, elev, azim)` in degrees.
pub fn camera_position_from_spherical_angles(dist: f64, elev_deg: f64, azim_deg: f64) -> DVec3 {
    let (elev, azim) = (elev_deg.to_radians(), azim_deg.to_radians());
    DVec3::new(
        dist * elev.cos() * azim.sin(),
        dist * elev.sin(),
        dist * elev.cos() * azim.cos(),
    )
}

/// The homework's `create_surround_cameras(radius, n_poses, up, focal_length)`.
///
/// θ runs over `linspace(0, 2π, n_poses + 1)` without the last value. For `up = (0, 1, 0)`
/// (any up with a non-zero y) the eye is `(cos(θ+π/2)·r, 0, −sin(θ+π/2)·r)`, otherwise
/// `(cos(θ+π/2)·r, sin(θ+π/2)·r, 2.0)`; every camera looks at the origin.
pub fn surround_cameras(
    radius: f64,
    n_poses: usize,
    up: DVec3,
    focal: f64,
) -> Vec<PerspectiveCamera> {
    let step = 2.0 * std::f64::consts::PI / n_poses as f64;
    (0..n_poses)
        .map(|i| {
            let theta = i as f64 * step + std::f64::consts::FRAC_PI_2;
            let eye = if up.y.abs() > 0.0 {
                DVec3::new(theta.cos() * radius, 0.0, -theta.sin() * radius)
            } else {
                DVec3::new(theta.cos() * radius, theta.sin() * radius, 2.0)
            };
            let (r, t) = look_at_view_transform(eye, DVec3::ZERO, up);
            PerspectiveCamera::new(r, t, focal)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
        (a - b).abs().max_element() <= tol
    }

    /// `look_at_view_transform(eye, 0, +y)` gives `expected_r` and `expected_t` to 1e-12.
    fn assert_look_at(eye: DVec3, expected_r: [[f64; 3]; 3], expected_t: DVec3) {
        let (r, t) = look_at_view_transform(eye, DVec3::ZERO, DVec3::Y);
        for i in 0..3 {
            for j in 0..3 {
                assert!((r[i][j] - expected_r[i][j]).abs() < 1e-12, "R[{i}][{j}]");
            }
        }
        assert!(close(DVec3::from_array(t), expected_t, 1e-12));
    }

    #[test]
    fn look_at_from_positive_z_and_x_matches_hand_computed_matrices() {
        // (eye, R, T). Eye on +z looking at the origin with y up: z axis = (0,0,-1),
        // x = up × z = (0,1,0)×(0,0,-1) = (-1,0,0), y = z × x = (0,1,0);
        // T = -Rᵀ eye = -(0,0,-3) = (0,0,3).
        // Eye (2,0,0): z = (-1,0,0), x = (0,1,0)×(-1,0,0) = (0,0,1), y = z×x = (0,1,0).
        let cases = [
            (
                [0.0, 0.0, 3.0],
                [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]],
                [0.0, 0.0, 3.0],
            ),
            (
                [2.0, 0.0, 0.0],
                [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],
                [0.0, 0.0, 2.0],
            ),
        ];
        for (eye, r, t) in cases {
            assert_look_at(DVec3::from_array(eye), r, DVec3::from_array(t));
        }
    }

    #[test]
    fn look_at_with_up_parallel_to_view_direction_stays_finite() {
        let (r, t) = look_at_view_transform(DVec3::new(0.0, 3.0, 0.0), DVec3::ZERO, DVec3::Y);
        assert!(r.iter().flatten().chain(t.iter()).all(|v| v.is_finite()));
    }

    #[test]
    fn camera_centre_recovers_the_eye() {
        for cam in surround_cameras(3.0, 7, DVec3::Y, 1.0)
            .into_iter()
            .chain(surround_cameras(4.0, 5, DVec3::Z, 2.0))
        {
            let c = cam.center();
            // The eye is at distance r (y up) or sqrt(r² + 4) (z up) from the origin and
            // the origin projects to the principal point.
            let o = cam.project(DVec3::ZERO);
            assert!(
                o.x.abs() < 1e-12 && o.y.abs() < 1e-12,
                "origin not centred: {o}"
            );
            assert!((o.z - c.length()).abs() < 1e-12);
            assert!(close(cam.world_to_view(c), DVec3::ZERO, 1e-12));
        }
    }

    #[test]
    fn surround_cameras_follow_the_homework_formula() {
        let cams = surround_cameras(3.0, 20, DVec3::Y, 1.0);
        assert_eq!(cams.len(), 20);
        // θ = 0: eye = (cos(π/2)·3, 0, -sin(π/2)·3) = (0, 0, -3).
        assert!(close(cams[0].center(), DVec3::new(0.0, 0.0, -3.0), 1e-12));
        // θ = π/2 (i = 5): eye = (cos(π)·3, 0, -sin(π)·3) = (-3, 0, 0).
        assert!(close(cams[5].center(), DVec3::new(-3.0, 0.0, 0.0), 1e-12));
        let lego = surround_cameras(4.0, 20, DVec3::Z, 2.0);
        // θ = 0: eye = (0, 4, 2).
        assert!(close(lego[0].center(), DVec3::new(0.0, 4.0, 2.0), 1e-12));
    }

    #[test]
    fn unproject_inverts_project() {
        let mut cam = surround_cameras(3.0, 20, DVec3::Y, 1.3)[3];
        cam.principal_point = [0.1, -0.2];
        cam.focal = [1.3, 0.9];
        let p = DVec3::new(0.3, -0.4, 0.5);
        let q = cam.project(p);
        let back = cam.unproject_ndc(q.x, q.y, q.z);
        assert!(close(back, p, 1e-12));
    }

    #[test]
    fn ndc_axes_are_left_up_forward() {
        // Camera at (0,0,-3) looking at the origin with y up: +X of NDC is world... the point
        // to the camera's left must have positive x_ndc, the point above positive y_ndc.
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[0];
        // Camera looks along +z; its left (pytorch3d +X) is world +x by the right-handed
        // look-at with up y: x = up × z = (0,1,0)×(0,0,1) = (1,0,0).
        assert!(cam.project(DVec3::new(0.5, 0.0, 0.0)).x > 0.0);
        assert!(cam.project(DVec3::new(0.0, 0.5, 0.0)).y > 0.0);
        assert!(cam.world_to_view(DVec3::ZERO).z > 0.0);
    }

    #[test]
    fn spherical_angles_match_pytorch3d() {
        let p = camera_position_from_spherical_angles(10.0, 0.0, 90.0);
        assert!(close(p, DVec3::new(10.0, 0.0, 0.0), 1e-9));
        let p = camera_position_from_spherical_angles(10.0, 90.0, 0.0);
        assert!(close(p, DVec3::new(0.0, 10.0, 0.0), 1e-9));
    }

    #[test]
    fn validate_rejects_non_finite() {
        let mut cam = surround_cameras(3.0, 1, DVec3::Y, 1.0)[0];
        assert!(cam.validate().is_ok());
        cam.t[1] = f64::NAN;
        assert!(cam.validate().is_err());
    }
}
