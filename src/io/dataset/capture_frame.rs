//! What a capture loader reads: each photo with its camera in the capture's own frame, and
//! the splits when the files name them. The loaders ([`super::colmap_scene`],
//! [`super::nerfstudio`], [`super::llff`]) produce it; [`super::capture`] normalises and
//! splits it.

use std::path::{Path, PathBuf};

use super::transforms::Split;
use crate::core::camera_colmap::ColmapCamera;

/// One photograph of a capture and its camera, in the capture's own world frame.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureFrame {
    /// The image file.
    pub file_path: PathBuf,
    /// Its camera.
    pub camera: ColmapCamera,
    /// Its mask ([`super::frame_mask`]), when it has one.
    pub mask_path: Option<PathBuf>,
    /// The nearest and farthest depth of the scene this camera sees, in the capture's own
    /// units, when the capture's files give them (LLFF's bounds).
    pub depth_bounds: Option<[f64; 2]>,
}

/// A capture's frames with their split named by the files, when they name it.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureFrames {
    /// Every frame.
    pub frames: Vec<CaptureFrame>,
    /// The splits each frame is in when the files say (nerfstudio's
    /// `{train,val,test}_filenames`; a frame may be in `val` and `test`); `None`: the
    /// every-8th holdout.
    pub splits: Option<Vec<Vec<Split>>>,
}

/// The folder of a COLMAP or LLFF capture that holds its masks, beside `images/`.
pub const MASKS_FOLDER: &str = "masks";

/// The mask of the photo `images/<name>` of the capture in `dir` when the capture has a
/// `masks/` folder: `masks/<name>` with the extension `.png` (nerfstudio's and instant-ngp's
/// layout); `None` without the folder. The file must then exist: loading it names it.
pub fn mask_in_folder(dir: &Path, name: &Path) -> Option<PathBuf> {
    let folder = dir.join(MASKS_FOLDER);
    folder
        .is_dir()
        .then(|| folder.join(name).with_extension("png"))
}
