//! A nerfstudio or instant-ngp capture: `transforms.json` as nerfstudio's `ns-process-data`
//! or instant-ngp's `scripts/colmap2nerf.py` writes it. The intrinsics keys of both tools
//! (`super::transforms_intrinsics`) stand at the top or per frame (a frame's own value
//! wins); instant-ngp's scene keys (`aabb_scale`, `scale`, `offset`, `super::ngp_scene`)
//! are checked and change nothing. `transform_matrix` is camera → world in OpenGL axes;
//! `file_path` (and a frame's optional `mask_path`, `super::frame_mask`) is relative to the
//! directory, and each photo is listed once. `train_filenames`, `val_filenames` and
//! `test_filenames`, when present, name the splits. `applied_transform` is the transform
//! nerfstudio already applied to the poses: the poses are read as they stand. Keys of neither
//! camera nor scene (colmap2nerf's per-frame `sharpness`, `fovx`, `up`, …) are ignored.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use serde::Deserialize;

use super::capture_frame::{CaptureFrame, CaptureFrames};
use super::scene_format::{FormatRead, SceneFormat};
use super::dataset_error::{metadata_unless_camera, read_dataset_file};
use super::ngp_scene::NgpSceneKeys;
use super::split::Split;
use super::transforms_intrinsics::Intrinsics;
use nerf_core::camera::ColmapCamera;

/// A nerfstudio or instant-ngp capture: a folder with `transforms.json`.
pub const NERFSTUDIO: SceneFormat = SceneFormat {
    key: "nerfstudio",
    name: "nerfstudio or instant-ngp (transforms.json)",
    marks: "transforms.json (nerfstudio or instant-ngp)",
    holds: |dir| dir.join("transforms.json").is_file(),
    listing: |dir| dir.join("transforms.json"),
    read: Some(|dir| Ok(FormatRead::own(NERFSTUDIO, read_frames(dir)?))),
};

/// Largest `transforms.json` read.
pub(crate) const MAX_TRANSFORMS_BYTES: u64 = 64 << 20;

#[derive(Debug, Deserialize)]
struct FrameEntry {
    file_path: String,
    mask_path: Option<String>,
    transform_matrix: Vec<[f64; 4]>,
    #[serde(flatten)]
    intrinsics: Intrinsics,
}

#[derive(Debug, Deserialize)]
struct TransformsJson {
    #[serde(flatten)]
    intrinsics: Intrinsics,
    #[serde(flatten)]
    ngp: NgpSceneKeys,
    frames: Vec<FrameEntry>,
    train_filenames: Option<Vec<String>>,
    val_filenames: Option<Vec<String>>,
    test_filenames: Option<Vec<String>>,
}

/// The frames of `dir/transforms.json`.
pub(crate) fn read_frames(dir: &Path) -> Result<CaptureFrames> {
    let path = dir.join("transforms.json");
    let bytes = read_dataset_file(&path, "transforms.json", MAX_TRANSFORMS_BYTES)?;
    parse(&bytes, dir, &path)
}

/// [`read_frames`] of the file's `bytes` (read from `path`, in `dir`). A frame's camera error
/// keeps its [`nerf_core::camera::CameraError`] in the chain; every other error is a
/// [`super::DatasetError::Metadata`] (inside the `anyhow::Error`).
pub(crate) fn parse(bytes: &[u8], dir: &Path, path: &Path) -> Result<CaptureFrames> {
    parse_frames(bytes, dir, path).map_err(|e| metadata_unless_camera(path, e))
}

/// [`parse`], its errors as they come.
fn parse_frames(bytes: &[u8], dir: &Path, path: &Path) -> Result<CaptureFrames> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let file: TransformsJson = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| anyhow!("cannot parse {}: {e}", path.display()))?;
    file.intrinsics
        .check()
        .and_then(|_| file.ngp.check(file.frames.len()))
        .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    let frames = file
        .frames
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            // As context, so that a camera's error stays in the chain.
            let context = |e: anyhow::Error| {
                e.context(format!(
                    "{}: frame {i} ({})",
                    path.display(),
                    entry.file_path
                ))
            };
            let m = &entry.transform_matrix;
            if m.len() != 3 && m.len() != 4 {
                return Err(context(anyhow!(
                    "transform_matrix has {} rows, not 3 or 4",
                    m.len()
                )));
            }
            if m.iter().flatten().any(|v| !v.is_finite()) {
                return Err(context(anyhow!("transform_matrix is not finite")));
            }
            let own = &entry.intrinsics;
            let intrinsics = own
                .check()
                .and_then(|_| own.resolve(&file.intrinsics))
                .map_err(context)?;
            let camera =
                ColmapCamera::from_nerfstudio([m[0], m[1], m[2]], &intrinsics).map_err(context)?;
            let mask_path = entry.mask_path.as_deref();
            Ok(CaptureFrame {
                file_path: relative_path(dir, &entry.file_path).map_err(context)?,
                camera,
                mask_path: mask_path
                    .map(|m| relative_path(dir, m))
                    .transpose()
                    .map_err(context)?,
                depth_bounds: None,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    refuse_duplicates(&frames, path)?;
    let splits = named_splits(&file, &frames, dir, path)?;
    let from_sfm = super::capture_frame::cameras_from_sfm(dir, false);
    let camera_source = path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    Ok(CaptureFrames {
        frames,
        splits,
        from_sfm,
        sfm_residual: None,
        camera_source,
    })
}

/// `dir/file_path` for a relative path without `..`; an error otherwise.
fn relative_path(dir: &Path, file_path: &str) -> Result<PathBuf> {
    let p = Path::new(file_path);
    if p.components().any(|c| {
        matches!(
            c,
            Component::ParentDir | Component::RootDir | Component::Prefix(_)
        )
    }) {
        bail!("file_path must be relative to the capture, without `..`");
    }
    Ok(dir.join(
        p.components()
            .filter(|c| !matches!(c, Component::CurDir))
            .collect::<PathBuf>(),
    ))
}

/// An error naming the first frame whose photo an earlier frame already lists (two poses
/// for one photo would train it twice, as two views).
fn refuse_duplicates(frames: &[CaptureFrame], path: &Path) -> Result<()> {
    let mut first_of: HashMap<&Path, usize> = HashMap::new();
    for (i, frame) in frames.iter().enumerate() {
        if let Some(first) = first_of.insert(&frame.file_path, i) {
            bail!(
                "{}: frame {i} lists {}, as frame {first} does: each photo may be listed once",
                path.display(),
                frame.file_path.display()
            );
        }
    }
    Ok(())
}

/// The splits of each frame from `{train,val,test}_filenames` when the file has them; `None`
/// otherwise. A frame in none of them is an error, and so is one in `train_filenames` and a
/// held-out list (it would be scored on a view it was trained on); `val_filenames` and
/// `test_filenames` may share frames.
fn named_splits(
    file: &TransformsJson,
    frames: &[CaptureFrame],
    dir: &Path,
    path: &Path,
) -> Result<Option<Vec<Vec<Split>>>> {
    let lists = [
        (Split::Train, &file.train_filenames),
        (Split::Val, &file.val_filenames),
        (Split::Test, &file.test_filenames),
    ];
    if lists.iter().all(|(_, l)| l.is_none()) {
        return Ok(None);
    }
    let mut splits_of: HashMap<PathBuf, Vec<Split>> = HashMap::new();
    for (split, list) in lists {
        for name in list.iter().flatten() {
            let splits = splits_of.entry(relative_path(dir, name)?).or_default();
            if !splits.contains(&split) {
                splits.push(split);
            }
            let trained = splits.contains(&Split::Train);
            if let Some(held_out) = splits.iter().find(|s| trained && **s != Split::Train) {
                bail!(
                    "{}: {name} is in both train_filenames and {held_out}_filenames: a \
                     held-out frame must not be trained on",
                    path.display()
                );
            }
        }
    }
    frames
        .iter()
        .map(|f| {
            splits_of.get(&f.file_path).cloned().ok_or_else(|| {
                anyhow!(
                    "{}: {} is in none of train_filenames, val_filenames, test_filenames",
                    path.display(),
                    f.file_path.display()
                )
            })
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOP: &str = r#""camera_model": "OPENCV", "fl_x": 500, "fl_y": 510, "cx": 320, "cy": 240, "w": 640, "h": 480, "k1": -0.1"#;

    fn frame(name: &str, extra: &str) -> String {
        format!(
            r#"{{"file_path": "images/{name}", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]{extra}}}"#
        )
    }

    #[test]
    fn intrinsics_at_the_top_or_per_frame() {
        let json = format!(
            r#"{{{TOP}, "frames": [{}, {}]}}"#,
            frame("a.jpg", ""),
            frame("b.jpg", r#", "fl_x": 700, "k1": 0.0"#)
        );
        let dir = Path::new("/cap");
        let read = parse(json.as_bytes(), dir, &dir.join("transforms.json")).unwrap();
        assert_eq!(read.splits, None);
        let [a, b] = [&read.frames[0], &read.frames[1]];
        assert_eq!(a.file_path, PathBuf::from("/cap/images/a.jpg"));
        assert_eq!(a.camera.focal, [500.0, 510.0]);
        assert_eq!(b.camera.focal, [700.0, 510.0]);
        assert_ne!(a.camera.distortion, b.camera.distortion);
        assert_eq!(a.camera.size, (640, 480));
    }

    #[test]
    fn named_splits_and_errors_name_the_frame() {
        let json = format!(
            r#"{{{TOP}, "frames": [{}, {}], "train_filenames": ["images/a.jpg"], "test_filenames": ["images/b.jpg"]}}"#,
            frame("a.jpg", ""),
            frame("b.jpg", "")
        );
        let dir = Path::new("/cap");
        let read = parse(json.as_bytes(), dir, &dir.join("transforms.json")).unwrap();
        assert_eq!(
            read.splits,
            Some(vec![vec![Split::Train], vec![Split::Test]])
        );
        let no_focal = format!(
            r#"{{"w": 4, "h": 4, "cx": 2, "cy": 2, "frames": [{}]}}"#,
            frame("a.jpg", "")
        );
        let err = parse(no_focal.as_bytes(), dir, &dir.join("transforms.json"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("frame 0 (images/a.jpg)") && err.contains("no fl_x"),
            "{err}"
        );
        let escape = format!(r#"{{{TOP}, "frames": [{}]}}"#, frame("../../etc/x.jpg", ""));
        let err = parse(escape.as_bytes(), dir, &dir.join("transforms.json")).unwrap_err();
        assert!(err.to_string().contains("without `..`"), "{err}");
    }

    #[test]
    fn a_colmap2nerf_file_loads() {
        // colmap2nerf.py's output for one PINHOLE camera: floats, aabb_scale, sharpness.
        let json = format!(
            r#"{{"camera_angle_x": 1.1760052070951352, "camera_angle_y": 0.9272952180016122,
            "fl_x": 500.0, "fl_y": 500.0, "k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0,
            "p1": 0.0, "p2": 0.0, "is_fisheye": false, "cx": 320.0, "cy": 240.0,
            "w": 640.0, "h": 480.0, "aabb_scale": 16, "frames": [{}, {}]}}"#,
            frame("a.jpg", r#", "sharpness": 341.5"#),
            frame(
                "b.jpg",
                r#", "sharpness": 12.25, "w": 320.0, "h": 240.0, "cx": 160.0, "cy": 120.0, "camera_angle_x": 1.5707963267948966"#
            )
        );
        let dir = Path::new("/cap");
        let read = parse(json.as_bytes(), dir, &dir.join("transforms.json")).unwrap();
        let [a, b] = [&read.frames[0].camera, &read.frames[1].camera];
        assert_eq!((a.size, a.focal), ((640, 480), [500.0, 500.0]));
        // The second frame's own field of view: 90° across 320 px; fl_y from the top.
        assert_eq!(b.size, (320, 240));
        assert!(
            (b.focal[0] - 160.0).abs() < 1e-9 && b.focal[1] == 500.0,
            "{b:?}"
        );
        let bad = json.replacen(r#""aabb_scale": 16"#, r#""aabb_scale": -1"#, 1);
        let err = parse(bad.as_bytes(), dir, &dir.join("transforms.json")).unwrap_err();
        assert_eq!(
            err.to_string(),
            "/cap/transforms.json: aabb_scale = -1 is not a positive number"
        );
    }

    #[test]
    fn a_photo_listed_twice_or_trained_and_held_out_is_named() {
        let dir = Path::new("/cap");
        let path = dir.join("transforms.json");
        let twice = format!(
            r#"{{{TOP}, "frames": [{}, {}, {}]}}"#,
            frame("a.jpg", ""),
            frame("b.jpg", ""),
            frame("a.jpg", "").replace("images/a.jpg", "./images/./a.jpg")
        );
        let err = parse(twice.as_bytes(), dir, &path).unwrap_err().to_string();
        assert_eq!(
            err,
            "/cap/transforms.json: frame 2 lists /cap/images/a.jpg, as frame 0 does: each \
             photo may be listed once"
        );
        let splits = |lists: &str| {
            let json = format!(
                r#"{{{TOP}, "frames": [{}, {}], {lists}}}"#,
                frame("a.jpg", ""),
                frame("b.jpg", "")
            );
            parse(json.as_bytes(), dir, &path).map(|r| r.splits.unwrap())
        };
        let err = splits(
            r#""train_filenames": ["images/a.jpg", "images/b.jpg"], "test_filenames": ["images/b.jpg"]"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.starts_with(
                "/cap/transforms.json: images/b.jpg is in both train_filenames and test_filenames"
            ),
            "{err}"
        );
        // val and test may share frames.
        let shared = splits(
            r#""train_filenames": ["images/a.jpg"], "val_filenames": ["images/b.jpg"], "test_filenames": ["./images/b.jpg"]"#,
        )
        .unwrap();
        assert_eq!(
            shared,
            vec![vec![Split::Train], vec![Split::Val, Split::Test]]
        );
    }
}
