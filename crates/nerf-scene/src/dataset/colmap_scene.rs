//! A COLMAP capture: the sparse model that [`crate::colmap::find_model`] finds (the one
//! with the most registered images when there are several) and its photos in `images/`
//! (subfolders allowed, as COLMAP's image names carry them), with masks in `masks/` when that
//! folder is there (`mask_in_folder`).

use std::path::Path;

use anyhow::{Context, Result};

use super::capture_frame::{mask_in_folder, CaptureFrame, CaptureFrames};
use super::dataset_error::DatasetError;
use super::scene_format::{FormatRead, SceneFormat};
use crate::colmap::{find_model, find_model_folder};
use nerf_core::camera::{ColmapCamera, ColmapPose};
use nerf_core::term::error_line;

/// A COLMAP capture: a folder with a sparse model (`sparse/0/`, `sparse/`, or the model's
/// files at the top) and its photos.
pub const COLMAP: SceneFormat = SceneFormat {
    key: "colmap",
    name: "COLMAP",
    marks: "a COLMAP model (sparse/0/ with its cameras, images and points3D files)",
    holds: |dir| find_model_folder(dir).is_some(),
    listing: |dir| dir.to_path_buf(),
    read: Some(|dir| Ok(FormatRead::own(COLMAP, read_frames(dir)?))),
};

/// Every registered image of the capture in `dir`, with its camera. A model that does not
/// read is a [`DatasetError::Metadata`], a missing `images/` a [`DatasetError::MissingFile`]
/// (inside the `anyhow::Error`); a camera's error keeps its
/// [`nerf_core::camera::CameraError`] in the chain.
pub(crate) fn read_frames(dir: &Path) -> Result<CaptureFrames> {
    let (model_dir, model) =
        find_model(dir).map_err(|e| DatasetError::metadata(dir, error_line(e.as_ref())))?;
    let images = dir.join("images");
    if !images.is_dir() {
        let message = format!(
            "{}: no such folder (a COLMAP capture keeps its photos in images/, beside the \
             sparse model {})",
            images.display(),
            model_dir.display()
        );
        return Err(DatasetError::missing_file(&images, message).into());
    }
    // The file the cameras were read from: binary files win when both are there.
    let cameras_file = ["cameras.bin", "cameras.txt"]
        .map(|f| model_dir.join(f))
        .into_iter()
        .find(|f| f.is_file())
        .unwrap_or_else(|| model_dir.join("cameras.txt"));
    let frames = model
        .images
        .iter()
        .map(|image| {
            let record = model.camera_of(image);
            let what = || format!("{}: image {}", model_dir.display(), image.name);
            // As context, so that a camera's error stays in the chain.
            let pose = ColmapPose::from_quaternion(image.qvec, image.tvec).with_context(what)?;
            let size = (record.width as usize, record.height as usize);
            let camera = ColmapCamera::from_colmap(&record.model, &record.params, size, pose)
                .with_context(|| {
                    format!(
                        "{}: camera {} (of image {})",
                        cameras_file.display(),
                        record.id,
                        image.name
                    )
                })?;
            Ok(CaptureFrame {
                file_path: images.join(&image.name),
                camera,
                mask_path: mask_in_folder(dir, Path::new(&image.name)),
                depth_bounds: None,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let folder = model_dir.strip_prefix(dir).unwrap_or(&model_dir);
    let camera_source = match folder.as_os_str().is_empty() {
        true => "the COLMAP model".to_string(),
        false => format!("the COLMAP model {}", folder.display()),
    };
    Ok(CaptureFrames {
        frames,
        splits: None,
        from_sfm: !model.points.is_empty(),
        sfm_residual: mean_point_error(&model.points),
        camera_source,
    })
}

/// The mean of the points' reprojection errors (COLMAP's per-point `error`, pixels) over the
/// points with a finite, non-negative one; `None` when there are none.
fn mean_point_error(points: &[crate::colmap::ColmapPoint3D]) -> Option<f64> {
    let errors: Vec<f64> = points
        .iter()
        .map(|p| p.error)
        .filter(|e| e.is_finite() && *e >= 0.0)
        .collect();
    (!errors.is_empty()).then(|| errors.iter().sum::<f64>() / errors.len() as f64)
}
