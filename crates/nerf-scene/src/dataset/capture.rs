//! Captures: a user's own photographs with cameras from structure from motion, in one of the
//! formats other NeRF tools read, chosen by what the directory holds ([`SceneFormat::detect`]):
//!
//! * COLMAP ([`super::colmap_scene`]): a sparse model (`sparse/N/`, `sparse/`, the model
//!   files at the top, or nerfstudio's `colmap/sparse/N`) and the photos in `images/`;
//! * nerfstudio or instant-ngp ([`super::nerfstudio`]): `transforms.json`;
//! * LLFF ([`super::llff`]): `poses_bounds.npy` and `images/`, or the COLMAP model beside
//!   them when there is one and it registers every photo ([`super::camera_source`]);
//! * the NeRF-synthetic ("Blender") scenes, `transforms_{split}.json` ([`super::transforms`]).
//!
//! A capture's cameras keep their own models (distortion included, [`ColmapCamera`]), sized to
//! the photos on disk ([`super::photo_fit`]), and its world frame is normalised
//! ([`SceneTransform`]). Its splits: the frames sorted by image
//! name, every 8th (index % 8 == 0, from 0) held out as `test` (and `val`), the rest `train`,
//! as mip-NeRF 360 and nerfstudio evaluate, unless the files name the splits themselves.

use std::path::Path;

use anyhow::{bail, Result};

pub(crate) use super::capture_frame::{CaptureFrame, CaptureFrames};
use super::dataset_error::DatasetError;
use super::normalize::SceneTransform;
use super::scene_format::FormatRead;
pub use super::scene_format::SceneFormat;
use super::split::Split;
use super::transforms::Frame;
use nerf_core::camera::{ColmapCamera, ColmapPose};

/// Every this-many-th frame (by sorted image name, from 0) is held out for evaluation.
pub(crate) const HOLDOUT_EVERY: usize = 8;

/// How a capture's frames are split into training and held-out ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SplitProtocol {
    /// Every `HOLDOUT_EVERY`th frame of the photos sorted by name, from the first, held out.
    EveryEighth,
    /// The capture's own split lists (nerfstudio's `{train,val,test}_filenames`).
    Lists,
}

impl SplitProtocol {
    /// Which frames are held out, in words: `every 8th of the sorted photo names`.
    pub fn describe(self) -> &'static str {
        match self {
            SplitProtocol::EveryEighth => "every 8th of the sorted photo names",
            SplitProtocol::Lists => "the capture's own split lists",
        }
    }
}

/// Where a capture's cameras came from and how its frames are split, for messages.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureInfo {
    /// The format the cameras were read as (COLMAP for an LLFF folder whose COLMAP model
    /// was taken, `super::camera_source`).
    pub format: SceneFormat,
    /// The file they came from (`CaptureFrames::camera_source`).
    pub camera_source: String,
    /// How the frames are split.
    pub protocol: SplitProtocol,
    /// The photos' own `(width, height)` once loaded ([`super::Dataset`] fills it).
    pub photo_size: Option<(u32, u32)>,
}

/// A capture's split in the normalised frame, and the normalisation applied.
#[derive(Debug, Clone, PartialEq)]
pub struct CaptureSplit {
    /// The split's frames, sorted by image path.
    pub frames: Vec<Frame>,
    /// What was applied to every camera: the given transform, or else the one computed from
    /// all frames, so that every split shares it.
    pub transform: SceneTransform,
    /// The transform the capture's cameras give ([`SceneTransform::from_poses`] of all its
    /// frames), whether or not it was the one applied; `None` when they give none (one
    /// camera, say) and a stored transform was applied.
    pub from_cameras: Option<SceneTransform>,
    /// Frames in the whole capture.
    pub total_frames: usize,
    /// The nearest and farthest scene depth over all the capture's frames, in the normalised
    /// frame's units, when every frame gives bounds (`CaptureFrame::depth_bounds`).
    pub depth_bounds: Option<[f64; 2]>,
    /// Whether its cameras come from structure from motion
    /// ([`super::capture_frame::cameras_from_sfm`]).
    pub from_sfm: bool,
    /// The mean reprojection error of the capture's SfM points, in pixels, when it has them
    /// (`super::capture_frame::CaptureFrames::sfm_residual`).
    pub sfm_residual: Option<f64>,
    /// Where the cameras came from and how the frames are split.
    pub info: CaptureInfo,
}

/// The normalisation of a loaded capture: the transform applied to its cameras, and the one
/// its cameras give, which differ when a stored transform was given (a model trained on
/// another set of the scene's cameras); and the scene's depth bounds in the normalised frame
/// when the capture gives them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalisation {
    /// Applied to every camera.
    pub applied: SceneTransform,
    /// Computed from the capture's own cameras (`None`: they give none, one camera, say).
    pub from_cameras: Option<SceneTransform>,
    /// The capture's scene depth bounds in the normalised frame (`CaptureSplit::depth_bounds`).
    pub depth_bounds: Option<[f64; 2]>,
    /// Whether the capture's cameras come from structure from motion
    /// (`CaptureSplit::from_sfm`).
    pub from_sfm: bool,
    /// The mean reprojection error of the capture's SfM points, in pixels
    /// (`CaptureSplit::sfm_residual`).
    pub sfm_residual: Option<f64>,
}

impl Normalisation {
    /// Whether the applied transform is (to `1e-9` in the normalised frame) the one the
    /// capture's own cameras give.
    pub fn is_from_cameras(&self) -> bool {
        self.from_cameras
            .is_some_and(|c| self.applied.agrees_with(&c, 1e-9))
    }
}

/// An error when the photo or mask `file` of the capture in `dir` is itself a symbolic link
/// to a file outside both the capture and the folder the link sits in: the capture's own
/// paths may not leave it (`..` is refused), so neither may a link among its files. A linked
/// folder (`images/` on another disk) is followed: the check is on the file's own link.
fn check_link_stays_inside(dir: &Path, file: &Path) -> Result<()> {
    let is_link = file
        .symlink_metadata()
        .is_ok_and(|m| m.file_type().is_symlink());
    if !is_link {
        return Ok(());
    }
    let Ok(target) = file.canonicalize() else {
        // A dangling link: the reader names the missing file.
        return Ok(());
    };
    let inside = |folder: Option<&Path>| {
        folder
            .and_then(|f| f.canonicalize().ok())
            .is_some_and(|f| target.starts_with(f))
    };
    if !(inside(Some(dir)) || inside(file.parent())) {
        bail!(
            "{}: a symbolic link to {}, outside the capture {}: copy the file into the capture \
             (or link its whole folder)",
            file.display(),
            target.display(),
            dir.display()
        );
    }
    Ok(())
}

/// An error unless the scene normalisation `stored` in a checkpoint puts the capture's cameras
/// (`poses`, in the capture's own frame) within
/// [`MAX_NORMALISED_DISTANCE`](nerf_core::camera::checks::MAX_NORMALISED_DISTANCE) of the
/// centre, as the frame it was trained in put its cameras within 1: an overflowing stored
/// transform would otherwise train and score on nothing.
fn check_stored_frame(dir: &Path, stored: &SceneTransform, poses: &[ColmapPose]) -> Result<()> {
    let farthest = poses
        .iter()
        .map(|p| stored.apply_pose(p).center().length())
        .fold(
            0.0,
            |a: f64, d| if d.is_nan() { f64::INFINITY } else { a.max(d) },
        );
    let limit = nerf_core::camera::checks::MAX_NORMALISED_DISTANCE;
    if farthest > limit {
        bail!(
            "{}: the scene normalisation stored in the checkpoint (metadata scene_transform) \
             puts a camera {} from the centre, beyond {limit}: the model was trained with its \
             cameras within 1",
            dir.display(),
            nerf_core::term::short_number(farthest)
        );
    }
    Ok(())
}

/// Whether frame `index` (of the frames sorted by image name) belongs to `split` under the
/// every-8th holdout: `test` and `val` hold index % 8 == 0, `train` the rest.
pub(crate) fn in_holdout_split(index: usize, split: Split) -> bool {
    let held_out = index.is_multiple_of(HOLDOUT_EVERY);
    match split {
        Split::Train => !held_out,
        Split::Val | Split::Test => held_out,
    }
}

/// `split` of a capture read as `format` from `dir`, normalised by the transform its cameras
/// give. Errors name the directory and what is missing or wrong ([`DatasetError`]); a split
/// with no frames is an error.
pub fn read_capture_split(
    dir: &Path,
    format: SceneFormat,
    split: Split,
) -> Result<CaptureSplit, DatasetError> {
    read_capture_split_with(dir, format, split, None)
}

/// [`read_capture_split`] normalised by `stored` when given (the transform a model was trained
/// in, so that its cameras land where that model's did), else by the one the cameras give.
pub fn read_capture_split_with(
    dir: &Path,
    format: SceneFormat,
    split: Split,
    stored: Option<SceneTransform>,
) -> Result<CaptureSplit, DatasetError> {
    capture_split(dir, format, split, stored).map_err(DatasetError::from_anyhow)
}

/// [`read_capture_split_with`], its typed errors inside an `anyhow::Error`.
fn capture_split(
    dir: &Path,
    format: SceneFormat,
    split: Split,
    stored: Option<SceneTransform>,
) -> Result<CaptureSplit> {
    let Some(read_format) = format.read else {
        let message = format!("{}: not a capture", dir.display());
        return Err(DatasetError::no_dataset(dir, message).into());
    };
    let FormatRead {
        frames: read,
        cameras_from: camera_format,
        note,
    } = read_format(dir)?;
    if let Some(note) = note {
        log_once(note);
    }
    let CaptureFrames {
        mut frames,
        splits,
        from_sfm,
        sfm_residual,
        camera_source,
    } = read;
    if frames.is_empty() {
        // The file that lists the frames (a COLMAP model without images is refused by its
        // reader, which names its images file).
        let listing = (format.listing)(dir);
        let message = format!(
            "{}: the {} capture has no frames",
            listing.display(),
            format.name()
        );
        return Err(DatasetError::metadata(&listing, message).into());
    }
    for frame in &frames {
        let files = std::iter::once(&frame.file_path).chain(frame.mask_path.as_ref());
        for file in files {
            check_link_stays_inside(dir, file)?;
        }
    }
    if let Some(note) = super::photo_fit::fit_cameras_to_photos(dir, &camera_source, &mut frames)? {
        log_once(note);
    }
    let poses: Vec<_> = frames.iter().map(|f| f.camera.pose).collect();
    let (transform, from_cameras) = match stored {
        Some(stored) => (stored, SceneTransform::from_poses(&poses).ok()),
        None => {
            let computed = SceneTransform::from_poses(&poses).map_err(|e| {
                anyhow::anyhow!(
                    "{}: {e} ({} camera{}, the first {})",
                    dir.display(),
                    poses.len(),
                    if poses.len() == 1 { "" } else { "s" },
                    frames[0].file_path.display()
                )
            })?;
            (computed, Some(computed))
        }
    };
    if stored.is_some() {
        check_stored_frame(dir, &transform, &poses)?;
    }
    let total_frames = frames.len();
    let protocol = match splits {
        Some(_) => SplitProtocol::Lists,
        None => SplitProtocol::EveryEighth,
    };
    let depth_bounds = scene_depth_bounds(&frames, transform.scale);
    let mut indexed: Vec<(usize, CaptureFrame)> = frames.into_iter().enumerate().collect();
    indexed.sort_by(|a, b| a.1.file_path.cmp(&b.1.file_path));
    let chosen: Vec<Frame> = indexed
        .into_iter()
        .enumerate()
        .filter(|(sorted, (original, _))| match &splits {
            Some(s) => s[*original].contains(&split),
            None => in_holdout_split(*sorted, split),
        })
        .map(|(_, (_, f))| {
            let camera = ColmapCamera {
                pose: transform.apply_pose(&f.camera.pose),
                ..f.camera
            };
            Frame {
                file_path: f.file_path,
                camera: camera.into(),
                mask_path: f.mask_path,
            }
        })
        .collect();
    if chosen.is_empty() {
        bail!(
            "{}: the {split} split of this {}-frame capture is empty",
            dir.display(),
            total_frames
        );
    }
    Ok(CaptureSplit {
        frames: chosen,
        transform,
        from_cameras,
        total_frames,
        depth_bounds,
        from_sfm,
        sfm_residual,
        info: CaptureInfo {
            format: camera_format,
            camera_source,
            protocol,
            photo_size: None,
        },
    })
}

/// Logs `message` the first time this process is given it: a capture is read several times
/// in one run (its size, then each split), and what its loader noticed is said once.
pub(crate) fn log_once(message: String) {
    static SAID: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());
    let mut said = SAID.lock().unwrap_or_else(|e| e.into_inner());
    if !said.contains(&message) {
        log::info!("{message}");
        said.push(message);
    }
}

/// The smallest near and largest far bound of `frames`, times `scale` (a similarity scales
/// depths along every ray by its scale); `None` unless every frame has bounds.
fn scene_depth_bounds(frames: &[CaptureFrame], scale: f64) -> Option<[f64; 2]> {
    frames
        .iter()
        .try_fold([f64::INFINITY, 0.0], |[near, far], f| {
            let [n, x] = f.depth_bounds?;
            Some([near.min(n * scale), far.max(x * scale)])
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_eighth_frame_from_zero_is_held_out() {
        let test: Vec<usize> = (0..20)
            .filter(|&i| in_holdout_split(i, Split::Test))
            .collect();
        assert_eq!(test, vec![0, 8, 16]);
        let train = (0..20)
            .filter(|&i| in_holdout_split(i, Split::Train))
            .count();
        assert_eq!(train, 17);
        assert!(
            (0..20).all(|i| in_holdout_split(i, Split::Val) == in_holdout_split(i, Split::Test))
        );
    }

    #[test]
    fn a_link_among_the_files_may_not_leave_the_capture_but_a_linked_folder_may() {
        use std::os::unix::fs::symlink;
        let root = tempfile::tempdir().unwrap();
        let capture = root.path().join("capture");
        let elsewhere = root.path().join("elsewhere");
        std::fs::create_dir_all(capture.join("images")).unwrap();
        std::fs::create_dir_all(&elsewhere).unwrap();
        std::fs::write(elsewhere.join("secret.png"), b"x").unwrap();
        std::fs::write(capture.join("images").join("a.png"), b"x").unwrap();
        // A plain file, and a link to a file inside: fine.
        assert!(check_link_stays_inside(&capture, &capture.join("images/a.png")).is_ok());
        symlink(capture.join("images/a.png"), capture.join("images/b.png")).unwrap();
        assert!(check_link_stays_inside(&capture, &capture.join("images/b.png")).is_ok());
        // A link to a file outside: refused, naming both.
        symlink(elsewhere.join("secret.png"), capture.join("images/c.png")).unwrap();
        let err = check_link_stays_inside(&capture, &capture.join("images/c.png"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("c.png") && err.contains("secret.png"), "{err}");
        // A linked folder (images on another disk) is followed, with links among its files.
        let linked = root.path().join("linked");
        std::fs::create_dir_all(&linked).unwrap();
        symlink(&elsewhere, linked.join("images")).unwrap();
        symlink(elsewhere.join("secret.png"), elsewhere.join("d.png")).unwrap();
        assert!(check_link_stays_inside(&linked, &linked.join("images/secret.png")).is_ok());
        assert!(check_link_stays_inside(&linked, &linked.join("images/d.png")).is_ok());
    }
}
