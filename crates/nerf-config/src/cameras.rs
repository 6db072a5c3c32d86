//! The `cameras` section (extension): the surround views `nerf render` renders, any key left
//! out taking the default of the scene's kind.

use glam::DVec3;
use serde::Deserialize;

use super::implicit_function::ImplicitFunctionConfig;
use super::Config;
use nerf_core::camera::{surround_cameras, PerspectiveCamera};

/// `cameras` (extension): the surround views rendered by `nerf render`.
#[derive(Debug, Clone, PartialEq)]
pub struct CamerasConfig {
    /// Distance of the cameras from the origin (`cameras.radius`; default 3 for SDF, 4 for NeRF).
    pub radius: f64,
    /// Number of views around the scene (`cameras.n_poses`, default 20).
    pub n_poses: usize,
    /// Up vector of the cameras (`cameras.up`; default +Y for SDF, +Z for NeRF).
    pub up: [f64; 3],
    /// NDC focal length of the cameras (`cameras.focal_length`; default 1 for SDF, 2 for NeRF).
    pub focal_length: f64,
}

/// `cameras` as written: any key left out takes the scene type's default.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCamerasConfig {
    radius: Option<f64>,
    n_poses: Option<usize>,
    up: Option<[f64; 3]>,
    focal_length: Option<f64>,
}

/// The homework's render views: radius 3 with y up and focal 1 for SDF scenes; radius 4 with
/// z up and focal 2 for NeRF scenes; 20 poses.
fn default_cameras(f: &ImplicitFunctionConfig) -> CamerasConfig {
    if f.is_sdf_volume() {
        CamerasConfig {
            radius: 3.0,
            n_poses: 20,
            up: [0.0, 1.0, 0.0],
            focal_length: 1.0,
        }
    } else {
        CamerasConfig {
            radius: 4.0,
            n_poses: 20,
            up: [0.0, 0.0, 1.0],
            focal_length: 2.0,
        }
    }
}

impl CamerasConfig {
    /// The section as written, `given`, with every key left out taking the default of the
    /// scene `f` describes.
    pub(super) fn resolve(given: Option<RawCamerasConfig>, f: &ImplicitFunctionConfig) -> Self {
        let defaults = default_cameras(f);
        let given = given.unwrap_or_default();
        CamerasConfig {
            radius: given.radius.unwrap_or(defaults.radius),
            n_poses: given.n_poses.unwrap_or(defaults.n_poses),
            up: given.up.unwrap_or(defaults.up),
            focal_length: given.focal_length.unwrap_or(defaults.focal_length),
        }
    }

    /// The surround cameras: `n_poses` views around the origin at `radius`.
    pub(crate) fn surround_cameras(&self) -> Vec<PerspectiveCamera> {
        surround_cameras(
            self.radius,
            self.n_poses,
            DVec3::from_array(self.up),
            self.focal_length,
        )
    }
}

impl Config {
    /// The surround cameras of the `cameras` section.
    pub fn surround_cameras(&self) -> Vec<PerspectiveCamera> {
        self.cameras.surround_cameras()
    }
}
