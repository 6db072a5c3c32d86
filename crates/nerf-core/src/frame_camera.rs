//! The camera of one dataset frame: the camera kinds that dataset loaders produce, in one
//! enum so that a frame stays a plain value (`Clone`, `PartialEq`). A loader that brings a new
//! [`Camera`] kind adds one variant here.

use glam::DVec3;

use crate::camera::Camera;
use crate::camera::PerspectiveCamera;
use crate::camera_colmap::ColmapCamera;
use crate::camera_error::CameraError;

/// One frame's camera.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameCamera {
    /// A pytorch3d pinhole camera on the homework's pixel grid (the NeRF-synthetic scenes).
    Pinhole(PerspectiveCamera),
    /// A camera with pixel intrinsics and lens distortion in COLMAP's conventions (COLMAP,
    /// nerfstudio and LLFF captures).
    Colmap(ColmapCamera),
}

impl FrameCamera {
    /// The camera as a [`Camera`].
    pub(crate) fn model(&self) -> &dyn Camera {
        match self {
            FrameCamera::Pinhole(c) => c,
            FrameCamera::Colmap(c) => c,
        }
    }

    /// The pytorch3d camera of a NeRF-synthetic frame; `None` for a capture's camera.
    pub fn pinhole(&self) -> Option<&PerspectiveCamera> {
        match self {
            FrameCamera::Pinhole(c) => Some(c),
            FrameCamera::Colmap(_) => None,
        }
    }
}

impl From<PerspectiveCamera> for FrameCamera {
    fn from(camera: PerspectiveCamera) -> Self {
        FrameCamera::Pinhole(camera)
    }
}

impl From<ColmapCamera> for FrameCamera {
    fn from(camera: ColmapCamera) -> Self {
        FrameCamera::Colmap(camera)
    }
}

impl Camera for FrameCamera {
    fn center(&self) -> DVec3 {
        self.model().center()
    }

    fn unproject_ndc(&self, x: f64, y: f64, depth: f64) -> DVec3 {
        self.model().unproject_ndc(x, y, depth)
    }

    fn validate(&self) -> Result<(), CameraError> {
        self.model().validate()
    }

    fn ray_through_ndc(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        self.model().ray_through_ndc(x, y)
    }

    fn pixel_ray(&self, column: usize, row: usize, size: (usize, usize)) -> (DVec3, DVec3) {
        self.model().pixel_ray(column, row, size)
    }
}
