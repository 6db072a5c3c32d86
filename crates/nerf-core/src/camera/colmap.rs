//! Real cameras from COLMAP and nerfstudio captures: pixel intrinsics with lens distortion.
//!
//! Conventions (COLMAP's, `src/colmap/sensor/models.h` and the COLMAP docs):
//!
//! * **Pose**: world → camera, `X_cam = R · X_world + t` (column vectors), as COLMAP's
//!   `images.txt` stores it (`QW QX QY QZ TX TY TZ`, a Hamilton unit quaternion). The camera
//!   centre is `C = −Rᵀ t`.
//! * **Camera axes** (OpenCV): +x right, +y down, +z forward (into the scene).
//! * **Pixels**: `(u, v)` with `u` along the columns and `v` down the rows; the image's top-left
//!   corner is `(0, 0)` and the centre of pixel `(i, j)` (column `i`, row `j`) is
//!   `(i + 0.5, j + 0.5)`. A camera-space point projects to `u = f_x · x_d + c_x`,
//!   `v = f_y · y_d + c_y`, where `(x_d, y_d)` is the distorted point
//!   ([`crate::lens`]) of the normalised point `(X/Z, Y/Z)`.
//! * **Models** and their parameter lists, exactly COLMAP's: `SIMPLE_PINHOLE (f, cx, cy)`,
//!   `PINHOLE (fx, fy, cx, cy)`, `SIMPLE_RADIAL (f, cx, cy, k)`, `RADIAL (f, cx, cy, k1, k2)`,
//!   `OPENCV (fx, fy, cx, cy, k1, k2, p1, p2)`,
//!   `FULL_OPENCV (fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6)`,
//!   `OPENCV_FISHEYE (fx, fy, cx, cy, k1, k2, k3, k4)`.
//!
//! nerfstudio's `transforms.json` stores camera → world in OpenGL axes (+x right, +y up,
//! +z backward) instead; [`ColmapCamera::from_nerfstudio`] converts it.

use anyhow::{bail, ensure, Context, Result};
use glam::{DMat3, DQuat, DVec2, DVec3};

use super::{CameraError, Projection};
use crate::lens::{ColmapCameraModel, Fisheye, LensDistortion};

/// A camera pose as COLMAP stores it: world → camera, `X_cam = rotation · X_world + translation`
/// with OpenCV camera axes (+x right, +y down, +z forward).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColmapPose {
    /// The world → camera rotation `R` (acting on column vectors).
    pub rotation: DMat3,
    /// The world → camera translation `t`.
    pub translation: DVec3,
}

impl ColmapPose {
    /// A pose from COLMAP's `images.txt` quaternion `[qw, qx, qy, qz]` (Hamilton, normalised
    /// here) and translation `[tx, ty, tz]`; an error for a zero or non-finite quaternion.
    pub fn from_quaternion(
        [qw, qx, qy, qz]: [f64; 4],
        translation: [f64; 3],
    ) -> std::result::Result<Self, CameraError> {
        let q = DQuat::from_xyzw(qx, qy, qz, qw);
        let norm = q.length();
        if !(norm.is_finite() && norm > 1e-12) {
            return Err(CameraError::Pose {
                message: format!(
                    "COLMAP pose quaternion [{qw}, {qx}, {qy}, {qz}] is zero or not finite"
                ),
            });
        }
        Ok(Self {
            rotation: DMat3::from_quat(q / norm),
            translation: DVec3::from_array(translation),
        })
    }

    /// A pose from the world → camera rotation given row by row (`rotation[i][j]` = `R_ij`,
    /// as numpy prints it) and the translation.
    pub fn from_matrix(rotation: [[f64; 3]; 3], translation: [f64; 3]) -> Self {
        // from_cols_array_2d reads each inner array as a column: transposing gives R.
        Self {
            rotation: DMat3::from_cols_array_2d(&rotation).transpose(),
            translation: DVec3::from_array(translation),
        }
    }

    /// A pose from nerfstudio's camera → world matrix in OpenGL axes (+x right, +y up,
    /// +z backward): the top three rows of `transforms.json`'s `transform_matrix`, row by row.
    /// OpenCV's camera axes are OpenGL's with y and z negated, so the OpenCV camera → world
    /// rotation is the OpenGL one with its second and third columns negated; the world →
    /// camera pose is its inverse.
    pub fn from_opengl_camera_to_world(camera_to_world: [[f64; 4]; 3]) -> Self {
        let column = |j: usize| DVec3::from_array([0, 1, 2].map(|i| camera_to_world[i][j]));
        let camera_to_world_rotation = DMat3::from_cols(column(0), -column(1), -column(2));
        let rotation = camera_to_world_rotation.transpose();
        Self {
            rotation,
            translation: -(rotation * column(3)),
        }
    }

    /// Nerfstudio's camera → world matrix (4×4, row by row, OpenGL camera axes: +x right,
    /// +y up, +z backward) of this world → camera pose (OpenCV axes): the inverse of the pose,
    /// with the camera's y and z axes negated. The inverse of
    /// [`ColmapPose::from_opengl_camera_to_world`].
    pub fn opengl_camera_to_world(&self) -> [[f64; 4]; 4] {
        let rotation = self.rotation.transpose();
        let axes = [
            rotation.x_axis,
            -rotation.y_axis,
            -rotation.z_axis,
            self.center(),
        ];
        let mut m = [[0.0; 4]; 4];
        for (j, column) in axes.iter().enumerate() {
            for (i, value) in column.to_array().into_iter().enumerate() {
                m[i][j] = value;
            }
        }
        m[3][3] = 1.0;
        m
    }

    /// The camera centre in world space, `C = −Rᵀ t`.
    pub fn center(&self) -> DVec3 {
        -(self.rotation.transpose() * self.translation)
    }

    /// World point → camera-space point (OpenCV axes).
    pub(crate) fn world_to_camera(&self, point: DVec3) -> DVec3 {
        self.rotation * point + self.translation
    }

    /// Camera-space point → world point.
    pub(crate) fn camera_to_world(&self, point: DVec3) -> DVec3 {
        self.rotation.transpose() * (point - self.translation)
    }
}

/// nerfstudio's per-camera intrinsics, as `transforms.json` names them.
#[derive(Debug, Clone, PartialEq)]
pub struct NerfstudioIntrinsics {
    /// `camera_model`: `OPENCV` (radial `1 + k1 r² + k2 r⁴ + k3 r⁶ + k4 r⁸`, tangential p1 p2)
    /// or `OPENCV_FISHEYE` (k1..k4 in `θ`, p1 = p2 = 0).
    pub camera_model: String,
    /// `fl_x`, focal length along the columns in pixels.
    pub fl_x: f64,
    /// `fl_y`, focal length along the rows in pixels.
    pub fl_y: f64,
    /// `cx`, principal point column in pixels (COLMAP's convention: pixel centres at `i + 0.5`).
    pub cx: f64,
    /// `cy`, principal point row in pixels.
    pub cy: f64,
    /// `w`, image width in pixels.
    pub w: usize,
    /// `h`, image height in pixels.
    pub h: usize,
    /// Distortion coefficients `[k1, k2, k3, k4]` (absent keys are 0).
    pub k: [f64; 4],
    /// Tangential distortion `[p1, p2]` (absent keys are 0).
    pub p: [f64; 2],
}

/// A camera with pixel intrinsics and lens distortion in COLMAP's conventions (see the module
/// documentation): one of COLMAP's models, or nerfstudio's `OPENCV` / `OPENCV_FISHEYE`.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    /// World → camera pose.
    pub pose: ColmapPose,
    /// The image size `(width, height)` in pixels that the intrinsics refer to.
    pub size: (usize, usize),
    /// Focal lengths `[fx, fy]` in pixels.
    pub focal: [f64; 2],
    /// Principal point `[cx, cy]` in pixels.
    pub principal_point: [f64; 2],
    /// The lens distortion on the normalised plane.
    pub distortion: LensDistortion,
}

impl ColmapCamera {
    /// A camera of the COLMAP model `model_name` (as a `cameras.txt` line names it) with
    /// COLMAP's parameter list `params`, for images of `size = (width, height)` pixels. An
    /// error names an unknown model (listing the supported ones), a wrong parameter count, or
    /// what [`Camera::validate`](super::Camera::validate) rejects.
    pub fn from_colmap(
        model_name: &str,
        params: &[f64],
        size: (usize, usize),
        pose: ColmapPose,
    ) -> Result<Self> {
        let model = ColmapCameraModel::from_name(model_name)?;
        let (focal, principal_point, distortion) = model.intrinsics(params)?;
        let camera = Self {
            pose,
            size,
            focal,
            principal_point,
            distortion,
        };
        // The camera error stays in the chain, under the model's name, for a dataset to find
        // (`nerf::io::dataset::DatasetError::Camera`); callers add their context with
        // `.context`, never by formatting `{e}`, which would print only the model's name.
        camera
            .validate()
            .with_context(|| format!("COLMAP camera model {}", model.name))?;
        Ok(camera)
    }

    /// A camera from a nerfstudio frame: camera → world in OpenGL axes (the top three rows of
    /// `transform_matrix`, see [`ColmapPose::from_opengl_camera_to_world`]) and its intrinsics.
    /// Errors name an unsupported `camera_model`, tangential terms given to a fisheye, or what
    /// [`Camera::validate`](super::Camera::validate) rejects.
    pub fn from_nerfstudio(
        camera_to_world: [[f64; 4]; 3],
        intrinsics: &NerfstudioIntrinsics,
    ) -> Result<Self> {
        let NerfstudioIntrinsics { k, p, .. } = *intrinsics;
        let model = intrinsics.camera_model.as_str();
        let distortion = match model {
            "OPENCV" => LensDistortion::polynomial(k, p),
            "OPENCV_FISHEYE" => {
                ensure!(
                    p == [0.0, 0.0],
                    "nerfstudio camera_model OPENCV_FISHEYE has no tangential terms, \
                     but p1 = {}, p2 = {}",
                    p[0],
                    p[1]
                );
                LensDistortion::Fisheye(Fisheye { k })
            }
            other => bail!(
                "unsupported nerfstudio camera_model `{other}` (supported: OPENCV, OPENCV_FISHEYE)"
            ),
        };
        let mut pose = ColmapPose::from_opengl_camera_to_world(camera_to_world);
        // transforms.json files hold float32 matrices (nerfstudio's, NeRF-synthetic's): lego's
        // r_88 is 2e-6 from orthonormal. A rotation that close is replaced by the nearest one
        // (through its normalised quaternion), keeping the centre the file gives (its last
        // column: `pose.center()` of the unsnapped pose is `RᵀR` times it, off by as much as
        // the rotation is); anything farther is left for `validate` to reject.
        let r = pose.rotation;
        let off = (r.transpose() * r - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0_f64, |worst, v| worst.max(v.abs()));
        if off < 1e-4 && r.determinant() > 0.0 {
            let centre = DVec3::from_array([0, 1, 2].map(|i| camera_to_world[i][3]));
            pose.rotation = DMat3::from_quat(DQuat::from_mat3(&r).normalize());
            pose.translation = -(pose.rotation * centre);
        }
        let camera = Self {
            pose,
            size: (intrinsics.w, intrinsics.h),
            focal: [intrinsics.fl_x, intrinsics.fl_y],
            principal_point: [intrinsics.cx, intrinsics.cy],
            distortion,
        };
        camera
            .validate()
            .with_context(|| format!("nerfstudio camera_model {model}"))?;
        Ok(camera)
    }

    /// Unit world-space direction of the ray imaged at pixel coordinates `(u, v)` of the
    /// camera's own image size (fractional; the centre of pixel `(i, j)` is
    /// `(i + 0.5, j + 0.5)`): the distortion is removed by Newton's method
    /// (`LensDistortion::undistorted_direction`).
    pub fn direction_at_pixel(&self, u: f64, v: f64) -> DVec3 {
        let distorted = DVec2::new(
            (u - self.principal_point[0]) / self.focal[0],
            (v - self.principal_point[1]) / self.focal[1],
        );
        let camera = self.distortion.undistorted_direction(distorted);
        (self.pose.rotation.transpose() * camera).normalize()
    }

    /// Origin (the camera centre) and unit direction of the ray through the fractional pixel
    /// coordinates `(u, v)` of the camera's own image size.
    pub fn ray_through_pixel(&self, u: f64, v: f64) -> (DVec3, DVec3) {
        (self.pose.center(), self.direction_at_pixel(u, v))
    }

    /// Pixel coordinates `(u, v)` (own image size, distortion applied) at which the world
    /// point is imaged, or `None` when it is not in front of the camera (camera-space
    /// `z ≤ 0`). Points outside the image frame still get coordinates.
    pub fn project(&self, world_point: DVec3) -> Option<(f64, f64)> {
        let p = self.pose.world_to_camera(world_point);
        // Written so that a NaN depth is not in front either.
        if p.z.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let distorted = self.distortion.distort(DVec2::new(p.x / p.z, p.y / p.z));
        Some((
            self.focal[0] * distorted.x + self.principal_point[0],
            self.focal[1] * distorted.y + self.principal_point[1],
        ))
    }

    /// The pixel coordinates (own image size) of the homework NDC point `(x, y)` (+X left,
    /// +Y up, [−1, 1] across the image): `u = (1 − x) / 2 · width`, `v = (1 − y) / 2 · height`,
    /// so NDC `(1, 1)` is the image's top-left corner `(0, 0)` and `(−1, −1)` its bottom-right
    /// corner `(width, height)`.
    pub(crate) fn ndc_to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (1.0 - x) / 2.0 * self.size.0 as f64,
            (1.0 - y) / 2.0 * self.size.1 as f64,
        )
    }
}

impl Projection for ColmapCamera {
    fn center(&self) -> DVec3 {
        self.pose.center()
    }

    /// The point at camera-space depth `z = depth` on the ray through the pixel
    /// `ColmapCamera::ndc_to_pixel` gives; for a fisheye ray at or beyond 90° from the axis
    /// (no positive depth), the point at distance `depth` along the ray.
    fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3 {
        let (u, v) = self.ndc_to_pixel(x, y);
        let direction = self.pose.rotation * self.direction_at_pixel(u, v);
        let camera_point = if direction.z > 0.0 {
            direction * (depth / direction.z)
        } else {
            direction * depth
        };
        self.pose.camera_to_world(camera_point)
    }

    fn validate(&self) -> std::result::Result<(), CameraError> {
        let (width, height) = self.size;
        if width == 0 || height == 0 {
            return Err(CameraError::ImageSize { size: self.size });
        }
        let translation = self.pose.translation.to_array();
        let all_finite = self
            .pose
            .rotation
            .to_cols_array()
            .iter()
            .chain(&translation)
            .chain(&self.focal)
            .chain(&self.principal_point)
            .copied()
            .chain(self.distortion.coefficients())
            .all(f64::is_finite);
        if !all_finite {
            return Err(CameraError::NotFinite {
                values: "its rotation, translation, focal length, principal point or distortion",
            });
        }
        let [fx, fy] = self.focal;
        if !(fx > 0.0 && fy > 0.0) {
            return Err(CameraError::FocalLength {
                focal: self.focal,
                in_pixels: true,
            });
        }
        let r = self.pose.rotation;
        let orthogonality = (r.transpose() * r - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0_f64, |worst, v| worst.max(v.abs()));
        if !(orthogonality < 1e-6 && r.determinant() > 0.0) {
            return Err(CameraError::Rotation {
                orthogonality,
                determinant: r.determinant(),
            });
        }
        crate::camera::checks::check_intrinsics(
            self.size,
            self.focal,
            self.principal_point,
            &self.distortion,
        )
    }

    fn ndc_focal(&self) -> [f64; 2] {
        [
            self.focal[0] / (0.5 * self.size.0 as f64),
            self.focal[1] / (0.5 * self.size.1 as f64),
        ]
    }

    /// OpenCV axes (x right, y down, z forward): the rows of the world → camera rotation.
    fn viewing_axes(&self) -> (DVec3, DVec3) {
        (
            self.pose.rotation.row(2).normalize(),
            -self.pose.rotation.row(1).normalize(),
        )
    }

    fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let (u, v) = self.ndc_to_pixel(x, y);
        self.ray_through_pixel(u, v)
    }

    /// COLMAP's pixel convention: the ray through the centre `(column + 0.5, row + 0.5)` of
    /// the pixel in a `size = (width, height)` image. A size other than the camera's own (a
    /// downscaled image) scales the intrinsics by `width / own width` and `height / own
    /// height`, i.e. the pixel centre maps to `((column + 0.5) · own width / width, …)`.
    fn pixel_ray(&self, column: usize, row: usize, size: (usize, usize)) -> (DVec3, DVec3) {
        let u = (column as f64 + 0.5) * self.size.0 as f64 / size.0 as f64;
        let v = (row as f64 + 0.5) * self.size.1 as f64 / size.1 as f64;
        self.ray_through_pixel(u, v)
    }
}

#[cfg(test)]
#[path = "colmap_tests.rs"]
mod tests;
