//! Cameras: one type, [`Camera`], whose variant is the camera's kind, and each kind's pose,
//! projection and checks in a file of its own.
//!
//! * [`Camera::Pinhole`]: the homework's pytorch3d `PerspectiveCameras` (`pinhole.rs`): NDC
//!   focal length and principal point, the row-vector pose `X_view = X_world · R + T`, and
//!   `look_at_view_transform`.
//! * [`Camera::Colmap`]: a real camera of a COLMAP or nerfstudio capture (`colmap.rs`): pixel
//!   intrinsics, COLMAP's world → camera pose in OpenCV axes, and a lens, one file per lens
//!   model in [`crate::lens`] (none, radial–tangential, fisheye, field of view), which
//!   also lists the COLMAP camera models each reads.
//!
//! Rays ([`crate::rays::Rays`]), the renderer and the float64 reference take a [`Camera`].
//! A new kind is one file implementing the crate's `Projection` (the centre, NDC
//! unprojection, its checks, its NDC focal length and viewing axes, and optionally its own
//! ray and pixel conventions) and one line of the `camera_kinds!` list below. The checks every kind's intrinsics go through are
//! [`checks`], their typed error [`CameraError`]; [`alignment`] compares
//! sets of camera centres (a capture's against surveyed ones).

use glam::DVec3;

pub mod alignment;
pub mod checks;
mod error;

pub use colmap::{ColmapPose, NerfstudioIntrinsics};
pub use error::CameraError;
pub use pinhole::{
    camera_position_from_spherical_angles, look_at_rotation, look_at_view_transform,
    surround_cameras,
};

/// How a camera kind images the world: what [`Camera`] dispatches to, one impl a kind.
pub(crate) trait Projection {
    /// The camera centre in world space.
    fn center(&self) -> DVec3;

    /// The world-space point imaged at the NDC point `(x, y)` at view depth `depth`.
    fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3;

    /// An error naming what is wrong when the camera cannot image anything.
    fn validate(&self) -> Result<(), CameraError>;

    /// The NDC focal lengths `[f_x, f_y]`: the focal length over half the image width and
    /// height.
    fn ndc_focal(&self) -> [f64; 2];

    /// Unit viewing direction and unit image-up direction, in world space.
    fn viewing_axes(&self) -> (DVec3, DVec3);

    /// Origin and unit direction of the ray through the NDC point `(x, y)`: from the centre
    /// towards the point unprojected at depth 1.
    fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let origin = self.center();
        let target = self.unproject_ndc(x, y, 1.0);
        (origin, (target - origin).normalize())
    }

    /// Origin and unit direction of the ray through pixel `(column, row)` of a `size =
    /// (width, height)` image: by default the homework's pixel grid
    /// ([`crate::pixel_grid::homework_ndc`]).
    fn pixel_ray(&self, column: usize, row: usize, size: (usize, usize)) -> (DVec3, DVec3) {
        let [x, y] = crate::pixel_grid::homework_ndc(column, row, size);
        self.ray_through_ndc(x, y)
    }
}

/// Declares each camera kind's module, the [`Camera`] enum with one variant per kind, its
/// dispatch to the kinds' [`Projection`] impls, and a `From` for each kind.
macro_rules! camera_kinds {
    ($($(#[$doc:meta])* $variant:ident => $module:ident::$kind:ident,)+) => {
        $(mod $module; pub use $module::$kind;)+

        /// A camera: its pose and how it images the world, one variant per kind. What kinds
        /// answer differently is a method of `Projection`; a match on the kind is for what
        /// only one kind has (a COLMAP camera's pixel size), the others in a `_` arm.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Camera {
            $($(#[$doc])* $variant($kind),)+
        }

        impl Camera {
            /// The kind behind the trait every kind implements.
            fn projection(&self) -> &dyn Projection {
                match self {
                    $(Self::$variant(camera) => camera,)+
                }
            }
        }

        $(
            impl From<$kind> for Camera {
                fn from(camera: $kind) -> Self {
                    Self::$variant(camera)
                }
            }
        )+
    };
}

camera_kinds! {
    /// A pytorch3d pinhole camera on the homework's pixel grid (the NeRF-synthetic scenes,
    /// the homework's surround views).
    Pinhole => pinhole::PerspectiveCamera,
    /// A camera with pixel intrinsics and lens distortion in COLMAP's conventions (COLMAP,
    /// nerfstudio and LLFF captures).
    Colmap => colmap::ColmapCamera,
}

impl Camera {
    /// The camera centre in world space.
    pub fn center(&self) -> DVec3 {
        self.projection().center()
    }

    /// The world-space point imaged at the NDC point `(x, y)` (the homework's convention: +X
    /// left, +Y up, both in [-1, 1] across the image) at view depth `depth`.
    pub fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3 {
        self.projection().unproject_ndc(x, y, depth)
    }

    /// An error naming what is wrong when the camera cannot image anything (a non-finite or
    /// degenerate pose or intrinsics; see [`CameraError`]).
    pub fn validate(&self) -> Result<(), CameraError> {
        self.projection().validate()
    }

    /// Origin and unit direction of the ray through the NDC point `(x, y)`: from the centre
    /// towards the point unprojected at depth 1.
    pub fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        self.projection().ray_through_ndc(x, y)
    }

    /// The NDC focal lengths `[f_x, f_y]`: a pinhole camera's own, a pixel camera's focal
    /// length over half its image width and height.
    pub fn ndc_focal(&self) -> [f64; 2] {
        self.projection().ndc_focal()
    }

    /// Unit viewing direction and unit image-up direction, in world space.
    pub fn viewing_axes(&self) -> (DVec3, DVec3) {
        self.projection().viewing_axes()
    }

    /// Origin and unit direction of the ray through pixel `(column, row)` of a
    /// `width × height` image (row 0 the top). A pinhole camera takes the homework's pixel
    /// grid ([`crate::pixel_grid::homework_ndc`]: pixel centres reach the image's edges); a
    /// COLMAP camera its own convention (the centre of pixel `i` at `i + 0.5`).
    pub fn pixel_ray(&self, column: usize, row: usize, size: (usize, usize)) -> (DVec3, DVec3) {
        self.projection().pixel_ray(column, row, size)
    }

    /// The pytorch3d camera of a pinhole camera; `None` for a capture's camera.
    pub fn pinhole(&self) -> Option<&PerspectiveCamera> {
        match self {
            Camera::Pinhole(c) => Some(c),
            _ => None,
        }
    }
}
