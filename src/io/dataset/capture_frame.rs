//! What a capture loader reads: each photo with its camera in the capture's own frame, and
//! the splits when the files name them. The loaders ([`super::colmap_scene`],
//! [`super::nerfstudio`], [`super::llff`]) produce it; [`super::capture`] normalises and
//! splits it.

use std::path::PathBuf;

use super::transforms::Split;
use crate::core::camera_colmap::ColmapCamera;

/// One photograph of a capture and its camera, in the capture's own world frame.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureFrame {
    /// The image file.
    pub file_path: PathBuf,
    /// Its camera.
    pub camera: ColmapCamera,
}

/// A capture's frames with their split named by the files, when they name it.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureFrames {
    /// Every frame.
    pub frames: Vec<CaptureFrame>,
    /// The split of each frame when the files say (nerfstudio's `{train,val,test}_filenames`);
    /// `None`: the every-8th holdout.
    pub splits: Option<Vec<Split>>,
}
