//! An LLFF capture (nerf-pytorch's forward-facing scenes): `poses_bounds.npy`, an `(N, 17)`
//! float array, one row per photo of `images/` in sorted order. A row is a 3×5 matrix, row
//! by row, then the near and far depth bounds: the first three columns are the
//! camera → world rotation with LLFF's axes (down, right, backwards), the fourth the camera
//! centre, the fifth `[height, width, focal]` in pixels of the full-size photos. The bounds
//! do not normalise the scene (its cameras do, `super::normalize`); they place the focus
//! of the spiral that `render` and `view` show a forward-facing capture from
//! (`super::spiral`).

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};

use super::capture_frame::{mask_in_folder, CaptureFrame, CaptureFrames};
use super::camera_source::{choose_cameras, CamerasFrom};
use super::scene_format::{FormatRead, SceneFormat};
use super::dataset_error::{metadata_unless_camera, read_dataset_file, DatasetError};
use nerf_core::camera::{ColmapCamera, ColmapPose};
use nerf_files::npy::{parse_npy_header, MAX_HEADER_BYTES};

/// An LLFF capture: a folder with `poses_bounds.npy`, whose cameras come from the COLMAP
/// model beside it when that registers every photo (`super::camera_source`).
pub const LLFF: SceneFormat = SceneFormat {
    key: "llff",
    name: "LLFF (poses_bounds.npy)",
    marks: "poses_bounds.npy (LLFF)",
    holds: |dir| dir.join("poses_bounds.npy").is_file(),
    listing: |dir| dir.join("poses_bounds.npy"),
    read: Some(read_folder),
};

/// Most photos an LLFF capture may list.
pub(crate) const MAX_LLFF_FRAMES: u64 = 100_000;

/// The frames of the LLFF capture in `dir`. A frame's camera error keeps its
/// [`nerf_core::camera::CameraError`] in the chain; a missing `images/` is a
/// [`DatasetError::MissingFile`], anything else wrong with `poses_bounds.npy` a
/// [`DatasetError::Metadata`] (inside the `anyhow::Error`).
pub(crate) fn read_frames(dir: &Path) -> Result<CaptureFrames> {
    let path = dir.join("poses_bounds.npy");
    read_capture(dir, &path).map_err(|e| metadata_unless_camera(&path, e))
}

/// [`read_frames`] of `path`, its errors as they come.
fn read_capture(dir: &Path, path: &Path) -> Result<CaptureFrames> {
    let rows = read_rows(path)?;
    let images_dir = dir.join("images");
    let images = image_files(&images_dir)?;
    if images.len() != rows.len() {
        bail!(
            "{}: {} poses, but {} has {} images",
            path.display(),
            rows.len(),
            dir.join("images").display(),
            images.len()
        );
    }
    let frames = rows
        .iter()
        .zip(images)
        .enumerate()
        .map(|(i, (row, file_path))| {
            // As context, so that a camera's error stays in the chain.
            let camera =
                camera_of_row(row).with_context(|| format!("{}: row {i}", path.display()))?;
            let name = file_path.strip_prefix(&images_dir).unwrap_or(&file_path);
            let mask_path = mask_in_folder(dir, name);
            Ok(CaptureFrame {
                file_path,
                camera,
                mask_path,
                depth_bounds: depth_bounds_of_row(row),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(CaptureFrames {
        frames,
        splits: None,
        // LLFF's poses_bounds.npy is written by its imgs2poses.py from a COLMAP run.
        from_sfm: true,
        sfm_residual: None,
        camera_source: "poses_bounds.npy".to_string(),
    })
}

/// The camera of one `poses_bounds.npy` row: LLFF's (down, right, back) axes are OpenGL's
/// (right, up, back) as `[c₁, −c₀, c₂]`; a pinhole with the focal length at the centre.
pub(crate) fn camera_of_row(row: &[f64; 17]) -> Result<ColmapCamera> {
    let m = |r: usize, c: usize| row[5 * r + c];
    let opengl = [0, 1, 2].map(|r| [m(r, 1), -m(r, 0), m(r, 2), m(r, 3)]);
    let (h, w, f) = (m(0, 4), m(1, 4), m(2, 4));
    if !(h >= 1.0 && w >= 1.0 && h.fract() == 0.0 && w.fract() == 0.0 && h <= 1e6 && w <= 1e6) {
        bail!("image size {w}×{h} is not a positive whole number of pixels");
    }
    let size = (w as usize, h as usize);
    let pose = ColmapPose::from_opengl_camera_to_world(opengl);
    ColmapCamera::from_colmap("PINHOLE", &[f, f, w / 2.0, h / 2.0], size, pose)
}

/// The near and far depth bounds of a `poses_bounds.npy` row; `None` unless `0 < near ≤ far`
/// (tools that know no bounds write zeros).
pub(crate) fn depth_bounds_of_row(row: &[f64; 17]) -> Option<[f64; 2]> {
    let (near, far) = (row[15], row[16]);
    (near > 0.0 && far >= near).then_some([near, far])
}

/// The rows of an `(N, 17)` little-endian float64 or float32 array.
fn read_rows(path: &Path) -> Result<Vec<[f64; 17]>> {
    let max = MAX_LLFF_FRAMES * 17 * 8 + MAX_HEADER_BYTES as u64 + 12;
    let bytes = read_dataset_file(path, "LLFF poses", max)?;
    let npy = parse_npy_header(&bytes).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    let [n, 17] = npy.shape[..] else {
        bail!("{}: shape {:?}, not (N, 17)", path.display(), npy.shape);
    };
    if npy.fortran_order {
        bail!("{}: a Fortran-ordered array", path.display());
    }
    let item = match npy.descr.as_str() {
        "<f8" => 8,
        "<f4" => 4,
        other => bail!("{}: dtype {other}, not float64 or float32", path.display()),
    };
    let data = &bytes[npy.data_offset..];
    let expected = n.checked_mul(17 * item as u64);
    if expected != Some(data.len() as u64) {
        bail!(
            "{}: {} data bytes for shape ({n}, 17)",
            path.display(),
            data.len()
        );
    }
    let values: Vec<f64> = data
        .chunks_exact(item)
        .map(|b| match item {
            8 => f64::from_le_bytes(b.try_into().expect("8 bytes")),
            _ => f32::from_le_bytes(b.try_into().expect("4 bytes")) as f64,
        })
        .collect();
    if values.iter().any(|v| !v.is_finite()) {
        bail!("{}: a value is not finite", path.display());
    }
    Ok(values
        .chunks_exact(17)
        .map(|c| c.try_into().expect("17 values"))
        .collect())
}

/// The PNG and JPEG files of `dir`, sorted by name.
fn image_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| {
        let message = format!("cannot list {}: {e}", dir.display());
        match e.kind() {
            std::io::ErrorKind::NotFound => DatasetError::missing_file(dir, message).into(),
            _ => anyhow!(message),
        }
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
        })
        .collect();
    files.sort();
    Ok(files)
}

/// The frames of the LLFF capture in `dir`: from its COLMAP model when one is there and
/// registers every photo, else from `poses_bounds.npy` ([`super::camera_source`]); the format
/// the cameras came from; and the line that says which and why when both were there.
fn read_folder(dir: &Path) -> Result<FormatRead> {
    if crate::colmap::find_model_folder(dir).is_none() {
        return Ok(FormatRead::own(LLFF, read_frames(dir)?));
    }
    let colmap = super::colmap_scene::read_frames(dir);
    let (from, frames, note) = choose_cameras(dir, read_frames(dir), colmap)?;
    let cameras_from = match from {
        CamerasFrom::PosesBounds => LLFF,
        CamerasFrom::ColmapModel => super::colmap_scene::COLMAP,
    };
    Ok(FormatRead {
        frames,
        cameras_from,
        note: Some(note),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn an_llff_row_becomes_the_camera_it_describes() {
        // Camera at (1, 2, 3) looking down world −z with world +y up: in LLFF's axes the
        // columns are down = (0, −1, 0), right = (1, 0, 0), back = (0, 0, 1).
        let mut row = [0.0; 17];
        let rows = [
            [0.0, 1.0, 0.0, 1.0, 480.0],
            [-1.0, 0.0, 0.0, 2.0, 640.0],
            [0.0, 0.0, 1.0, 3.0, 500.0],
        ];
        for (r, values) in rows.iter().enumerate() {
            row[5 * r..5 * r + 5].copy_from_slice(values);
        }
        let camera = camera_of_row(&row).unwrap();
        assert_eq!(camera.size, (640, 480));
        assert!((camera.pose.center() - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
        // The image centre looks along −z; the top of the image is +y.
        let (_, d) = camera.ray_through_pixel(320.0, 240.0);
        assert!((d - DVec3::NEG_Z).length() < 1e-12);
        let (_, up) = camera.ray_through_pixel(320.0, 0.0);
        assert!(up.y > 0.0);
        // A point 500 px right of the centre at depth 1: +x.
        let (_, right) = camera.ray_through_pixel(320.0 + 500.0, 240.0);
        assert!((right - DVec3::new(1.0, 0.0, -1.0).normalize()).length() < 1e-12);
    }
}

/// An LLFF folder with a COLMAP model beside it ([`super::camera_source`]).
#[cfg(test)]
mod folder_tests {
    use super::*;
    use crate::dataset::capture::read_capture_split;
    use crate::dataset::colmap_scene::COLMAP;
    use crate::dataset::Split;

    /// The real capture bird_handheld (poses_bounds.npy beside its COLMAP model), when it is
    /// on this machine.
    fn bird() -> Option<PathBuf> {
        let dir =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real/bird_handheld");
        let found = dir.join("poses_bounds.npy").is_file() && dir.join("sparse").is_dir();
        if !found {
            eprintln!("skipping: {} not found", dir.display());
        }
        found.then_some(dir)
    }

    #[test]
    fn bird_handheld_takes_its_colmap_model_with_the_same_holdout() {
        let Some(dir) = bird() else { return };
        let FormatRead {
            frames: read,
            cameras_from,
            note,
        } = read_folder(&dir).unwrap();
        assert_eq!(cameras_from, COLMAP);
        let note = note.unwrap();
        assert_eq!(
            note,
            "bird_handheld: cameras from the COLMAP model sparse/0 (per-frame intrinsics), not \
             poses_bounds.npy (one shared focal); its depth bounds kept"
        );
        assert_eq!(read.frames.len(), 184);
        let focals: Vec<f64> = read.frames.iter().map(|f| f.camera.focal[0]).collect();
        let (low, high) = focals
            .iter()
            .fold((f64::INFINITY, 0.0_f64), |(l, h), &f| (l.min(f), h.max(f)));
        assert!(
            low >= 792.5 && high <= 1037.5 && high - low > 200.0,
            "{low} {high}"
        );
        assert!(read.frames.iter().all(|f| f.depth_bounds.is_some()));
        // The split: every 8th of the sorted names, the same photos as poses_bounds.npy's.
        let names = |split: Split, dir: &Path| -> Vec<String> {
            read_capture_split(dir, LLFF, split)
                .unwrap()
                .frames
                .iter()
                .map(|f| f.file_path.file_name().unwrap().to_string_lossy().into())
                .collect()
        };
        let test = names(Split::Test, &dir);
        assert_eq!(test.len(), 23);
        // poses_bounds.npy alone: its photos linked in.
        let alone = tempfile::tempdir().unwrap();
        std::fs::copy(
            dir.join("poses_bounds.npy"),
            alone.path().join("poses_bounds.npy"),
        )
        .unwrap();
        std::os::unix::fs::symlink(dir.join("images"), alone.path().join("images")).unwrap();
        let alone_read = read_folder(alone.path()).unwrap();
        assert_eq!((alone_read.cameras_from, alone_read.note), (LLFF, None));
        assert_eq!(names(Split::Test, alone.path()), test);
        assert_eq!(names(Split::Train, alone.path()), names(Split::Train, &dir));
    }
}
