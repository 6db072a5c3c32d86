//! A nerfstudio capture: `transforms.json` as `ns-process-data` writes it. Intrinsics
//! (`camera_model`, `fl_x fl_y cx cy w h`, `k1..k4 p1 p2`) stand at the top or per frame (a
//! frame's own value wins, nerfstudio's rule); `transform_matrix` is camera → world in OpenGL
//! axes; `file_path` (and a frame's optional `mask_path`, [`super::frame_mask`]) is relative
//! to the directory. `train_filenames`, `val_filenames` and
//! `test_filenames`, when present, name the splits. `applied_transform` is the transform
//! nerfstudio already applied to the poses: the poses are read as they stand.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use serde::Deserialize;

use super::capture_frame::{CaptureFrame, CaptureFrames};
use super::transforms::Split;
use crate::core::camera_colmap::{ColmapCamera, NerfstudioIntrinsics};
use crate::io::bounded_read::read_regular_file;

/// Largest `transforms.json` read.
pub const MAX_TRANSFORMS_BYTES: u64 = 64 << 20;

/// Intrinsics keys, each optional at the top and per frame.
#[derive(Debug, Clone, Default, Deserialize)]
struct Intrinsics {
    camera_model: Option<String>,
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<usize>,
    h: Option<usize>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
}

impl Intrinsics {
    /// `self`'s values, `top`'s where `self` has none.
    fn or(&self, top: &Intrinsics) -> Intrinsics {
        macro_rules! pick {
            ($($k:ident),*) => { Intrinsics { $($k: self.$k.clone().or(top.$k.clone())),* } };
        }
        pick!(
            camera_model,
            fl_x,
            fl_y,
            cx,
            cy,
            w,
            h,
            k1,
            k2,
            k3,
            k4,
            p1,
            p2
        )
    }

    /// The complete intrinsics; an error naming the first missing key.
    fn complete(self) -> Result<NerfstudioIntrinsics> {
        let need = |v: Option<f64>, k: &str| v.ok_or_else(|| anyhow!("no {k}"));
        let fl_x = need(self.fl_x, "fl_x")?;
        Ok(NerfstudioIntrinsics {
            camera_model: self.camera_model.unwrap_or_else(|| "OPENCV".into()),
            fl_x,
            // nerfstudio reads a missing fl_y as fl_x.
            fl_y: self.fl_y.unwrap_or(fl_x),
            cx: need(self.cx, "cx")?,
            cy: need(self.cy, "cy")?,
            w: self.w.ok_or_else(|| anyhow!("no w"))?,
            h: self.h.ok_or_else(|| anyhow!("no h"))?,
            k: [self.k1, self.k2, self.k3, self.k4].map(|k| k.unwrap_or(0.0)),
            p: [self.p1, self.p2].map(|p| p.unwrap_or(0.0)),
        })
    }
}

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
    frames: Vec<FrameEntry>,
    train_filenames: Option<Vec<String>>,
    val_filenames: Option<Vec<String>>,
    test_filenames: Option<Vec<String>>,
}

/// The frames of `dir/transforms.json`.
pub fn read_frames(dir: &Path) -> Result<CaptureFrames> {
    let path = dir.join("transforms.json");
    let bytes = read_regular_file(&path, "transforms.json", MAX_TRANSFORMS_BYTES)?;
    parse(&bytes, dir, &path)
}

/// [`read_frames`] of the file's `bytes` (read from `path`, in `dir`).
pub fn parse(bytes: &[u8], dir: &Path, path: &Path) -> Result<CaptureFrames> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let file: TransformsJson = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| anyhow!("cannot parse {}: {e}", path.display()))?;
    let frames = file
        .frames
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let context = |e: anyhow::Error| {
                anyhow!("{}: frame {i} ({}): {e}", path.display(), entry.file_path)
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
            let intrinsics = entry
                .intrinsics
                .or(&file.intrinsics)
                .complete()
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
    let splits = named_splits(&file, &frames, dir, path)?;
    Ok(CaptureFrames { frames, splits })
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

/// Each frame's split from `{train,val,test}_filenames` when the file has them (a frame in
/// none of them is an error); `None` otherwise.
fn named_splits(
    file: &TransformsJson,
    frames: &[CaptureFrame],
    dir: &Path,
    path: &Path,
) -> Result<Option<Vec<Split>>> {
    let lists = [
        (Split::Train, &file.train_filenames),
        (Split::Val, &file.val_filenames),
        (Split::Test, &file.test_filenames),
    ];
    if lists.iter().all(|(_, l)| l.is_none()) {
        return Ok(None);
    }
    let mut split_of: HashMap<PathBuf, Split> = HashMap::new();
    for (split, list) in lists {
        for name in list.iter().flatten() {
            split_of.insert(relative_path(dir, name)?, split);
        }
    }
    frames
        .iter()
        .map(|f| {
            split_of.get(&f.file_path).copied().ok_or_else(|| {
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
        assert_eq!(read.splits, Some(vec![Split::Train, Split::Test]));
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
}
