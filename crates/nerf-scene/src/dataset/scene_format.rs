//! The scene formats `--data-dir` takes, told apart by what the folder holds. Each format is
//! one [`SceneFormat`] value defined in the file that reads it (the NeRF-synthetic release in
//! `transforms.rs`, the captures of other NeRF tools in `nerfstudio.rs`, `llff.rs` and
//! `colmap_scene.rs`) and listed once, in the order they are tried, by the `scene_formats!`
//! line of `dataset/mod.rs` ([`super::SCENE_FORMATS`]).

use std::fmt;
use std::path::{Path, PathBuf};

use anyhow::Result;

use super::capture_frame::CaptureFrames;

/// A scene format: how a folder that holds it is recognised, named and read.
#[derive(Clone, Copy)]
pub struct SceneFormat {
    /// A short name for programs and logs (`colmap`).
    pub(crate) key: &'static str,
    /// The format's name as users know it, with the file that marks it.
    pub(crate) name: &'static str,
    /// What marks a folder of this format, as a message lists it (`poses_bounds.npy (LLFF)`).
    pub(crate) marks: &'static str,
    /// Whether `dir` holds a scene of this format (the file or folder that marks it).
    pub(crate) holds: fn(&Path) -> bool,
    /// The file that lists the frames of the scene in `dir`, named when it lists none.
    pub(crate) listing: fn(&Path) -> PathBuf,
    /// Every frame of the capture in `dir` (`None`: not a capture, but a dataset read split by
    /// split, as the NeRF-synthetic release is).
    pub(crate) read: Option<fn(&Path) -> Result<FormatRead>>,
}

/// What a capture format's reader gives: the frames, the format their cameras were read in
/// (an LLFF folder's may come from the COLMAP model beside it) and a line saying which and
/// why, when there was a choice.
pub(crate) struct FormatRead {
    pub(crate) frames: CaptureFrames,
    pub(crate) cameras_from: SceneFormat,
    pub(crate) note: Option<String>,
}

impl FormatRead {
    /// Frames whose cameras are `format`'s own, with nothing to say.
    pub(crate) fn own(format: SceneFormat, frames: CaptureFrames) -> Self {
        Self {
            frames,
            cameras_from: format,
            note: None,
        }
    }
}

impl SceneFormat {
    /// The format of `dir`: the first of `super::SCENE_FORMATS` that `dir` holds; the first
    /// listed (the NeRF-synthetic release) otherwise, whose reader then names the missing file.
    pub fn detect(dir: &Path) -> Self {
        let formats = super::SCENE_FORMATS;
        formats
            .iter()
            .find(|format| (format.holds)(dir))
            .copied()
            .unwrap_or(formats[0])
    }

    #[cfg(test)]
    /// The registered format whose [`SceneFormat::key`] is `key`.
    pub(crate) fn find(key: &str) -> Option<Self> {
        super::SCENE_FORMATS.iter().find(|f| f.key == key).copied()
    }

    #[cfg(test)]
    /// The format's short name (`blender`, `nerfstudio`, `llff`, `colmap`).
    pub(crate) fn key(self) -> &'static str {
        self.key
    }

    /// The format's name, as users know it.
    pub(crate) fn name(self) -> &'static str {
        self.name
    }

    /// What a folder of each registered format holds, as one message lists them:
    /// `transforms_{train,val,test}.json (NeRF-synthetic), …, poses_bounds.npy (LLFF) or …`.
    pub(crate) fn expected_files() -> String {
        let marks: Vec<&str> = super::SCENE_FORMATS.iter().map(|f| f.marks).collect();
        nerf_core::term::or_list(&marks)
    }

    #[cfg(test)]
    /// Whether the format is a capture, read whole and split by the held-out rule, rather
    /// than a dataset with split files of its own.
    pub(crate) fn is_capture(self) -> bool {
        self.read.is_some()
    }
}

impl PartialEq for SceneFormat {
    fn eq(&self, other: &Self) -> bool {
        self.key == other.key
    }
}

impl Eq for SceneFormat {}

impl fmt::Debug for SceneFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "SceneFormat({})", self.key)
    }
}

#[cfg(test)]
mod tests {
    use super::super::SCENE_FORMATS;
    use super::*;

    #[test]
    fn every_format_is_listed_once_and_found_by_its_key() {
        let keys: Vec<_> = SCENE_FORMATS.iter().map(|f| f.key()).collect();
        assert_eq!(keys, ["blender", "nerfstudio", "llff", "colmap"]);
        for format in SCENE_FORMATS {
            assert_eq!(SceneFormat::find(format.key()), Some(*format));
        }
        assert_eq!(SceneFormat::find("mesh"), None);
        assert!(!SceneFormat::find("blender").unwrap().is_capture());
        assert!(SceneFormat::find("colmap").unwrap().is_capture());
        assert_eq!(
            SceneFormat::expected_files(),
            "transforms_{train,val,test}.json (NeRF-synthetic), transforms.json (nerfstudio or \
             instant-ngp), poses_bounds.npy (LLFF) or a COLMAP model (sparse/0/ with its \
             cameras, images and points3D files)"
        );
    }

    #[test]
    fn a_folder_is_the_first_format_it_holds() {
        let dir = tempfile::tempdir().unwrap();
        // Nothing there: the NeRF-synthetic reader names what is missing.
        assert_eq!(SceneFormat::detect(dir.path()).key(), "blender");
        std::fs::write(dir.path().join("poses_bounds.npy"), b"").unwrap();
        assert_eq!(SceneFormat::detect(dir.path()).key(), "llff");
        std::fs::write(dir.path().join("transforms.json"), b"{}").unwrap();
        assert_eq!(SceneFormat::detect(dir.path()).key(), "nerfstudio");
        std::fs::write(dir.path().join("transforms_test.json"), b"{}").unwrap();
        assert_eq!(SceneFormat::detect(dir.path()).key(), "blender");
    }
}
