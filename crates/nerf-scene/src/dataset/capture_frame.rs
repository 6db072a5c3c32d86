//! What a capture loader reads: each photo with its camera in the capture's own frame, and
//! the splits when the files name them. The loaders ([`super::colmap_scene`],
//! [`super::nerfstudio`], [`super::llff`]) produce it; [`super::capture`] normalises and
//! splits it.

use std::path::{Path, PathBuf};

use super::split::Split;
use nerf_core::camera::ColmapCamera;

/// One photograph of a capture and its camera, in the capture's own world frame.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CaptureFrame {
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
pub(crate) struct CaptureFrames {
    /// Every frame.
    pub frames: Vec<CaptureFrame>,
    /// The splits each frame is in when the files say (nerfstudio's
    /// `{train,val,test}_filenames`; a frame may be in `val` and `test`); `None`: the
    /// every-8th holdout.
    pub splits: Option<Vec<Vec<Split>>>,
    /// Whether the files show the cameras to come from structure from motion
    /// ([`cameras_from_sfm`]).
    pub from_sfm: bool,
    /// The mean reprojection error in pixels of the 3D points structure from motion left with
    /// the cameras (a COLMAP model's `points3D`), when the files hold them: how far off its
    /// own cameras are by its own measure.
    pub sfm_residual: Option<f64>,
    /// The file the cameras were read from, for messages (`poses_bounds.npy`, `transforms.json`,
    /// `the COLMAP model sparse/0`).
    pub camera_source: String,
}

/// Whether a capture's cameras came from structure from motion, as far as its files show:
/// the points that SfM triangulates (`has_points`: a COLMAP model with 3D points), or the
/// COLMAP workspace that `nerf process`, nerfstudio's `ns-process-data` and instant-ngp's
/// `colmap2nerf.py` leave beside their `transforms.json` (`colmap/`, `colmap_sparse/`,
/// `colmap_text/`, `sparse/`). Cameras written from a calibration or a renderer come with
/// neither, and are not refined by `training.camera_refinement: auto`.
pub fn cameras_from_sfm(dir: &Path, has_points: bool) -> bool {
    has_points
        || ["colmap", "colmap_sparse", "colmap_text", "sparse"]
            .iter()
            .any(|folder| dir.join(folder).is_dir())
}

/// The folder of a COLMAP or LLFF capture that holds its masks, beside `images/`.
pub(crate) const MASKS_FOLDER: &str = "masks";

/// The mask of the photo `images/<name>` of the capture in `dir` when the capture has a
/// `masks/` folder: `masks/<name>` with the extension `.png` (nerfstudio's and instant-ngp's
/// layout); `None` without the folder. The file must then exist: loading it names it.
pub(crate) fn mask_in_folder(dir: &Path, name: &Path) -> Option<PathBuf> {
    let folder = dir.join(MASKS_FOLDER);
    folder
        .is_dir()
        .then(|| folder.join(name).with_extension("png"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sfm_cameras_are_told_by_points_or_a_colmap_workspace() {
        let dir = tempfile::tempdir().unwrap();
        assert!(!cameras_from_sfm(dir.path(), false));
        assert!(cameras_from_sfm(dir.path(), true));
        // A file of that name is not a workspace.
        std::fs::write(dir.path().join("colmap"), b"").unwrap();
        assert!(!cameras_from_sfm(dir.path(), false));
        std::fs::remove_file(dir.path().join("colmap")).unwrap();
        for folder in ["colmap", "colmap_sparse", "colmap_text", "sparse"] {
            let d = tempfile::tempdir().unwrap();
            std::fs::create_dir(d.path().join(folder)).unwrap();
            assert!(cameras_from_sfm(d.path(), false), "{folder}");
        }
    }
}
