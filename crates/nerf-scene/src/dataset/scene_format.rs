//! The dataset formats `--data-dir` takes, told apart by what the folder holds.

use std::path::Path;

use super::transforms::Split;

/// The dataset formats, by what their directory holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneFormat {
    /// NeRF-synthetic: `transforms_{train,val,test}.json`.
    Blender,
    /// nerfstudio: `transforms.json`.
    Nerfstudio,
    /// LLFF: `poses_bounds.npy`.
    Llff,
    /// COLMAP: a sparse model.
    Colmap,
}

impl SceneFormat {
    /// The format of `dir`: Blender when any `transforms_{split}.json` is there, else
    /// nerfstudio for `transforms.json`, LLFF for `poses_bounds.npy`, COLMAP for a sparse
    /// model; Blender otherwise (whose reader then names the missing file).
    pub fn detect(dir: &Path) -> Self {
        if Split::ALL.iter().any(|s| s.transforms_path(dir).is_file()) {
            SceneFormat::Blender
        } else if dir.join("transforms.json").is_file() {
            SceneFormat::Nerfstudio
        } else if dir.join("poses_bounds.npy").is_file() {
            SceneFormat::Llff
        } else if crate::colmap::find_model_folder(dir).is_some() {
            SceneFormat::Colmap
        } else {
            SceneFormat::Blender
        }
    }

    /// The format's name, as users know it.
    pub fn name(self) -> &'static str {
        match self {
            SceneFormat::Blender => "NeRF-synthetic (transforms_{split}.json)",
            SceneFormat::Nerfstudio => "nerfstudio or instant-ngp (transforms.json)",
            SceneFormat::Llff => "LLFF (poses_bounds.npy)",
            SceneFormat::Colmap => "COLMAP",
        }
    }
}
