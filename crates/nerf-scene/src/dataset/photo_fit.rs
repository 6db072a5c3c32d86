//! A capture's cameras sized to the photos on disk. Camera files are often written for larger
//! photos than the ones beside them (LLFF's `poses_bounds.npy` keeps the full-size `[h, w, f]`
//! while `images/` holds a downscaled copy; a COLMAP model or `transforms.json` made at full
//! size before the photos were shrunk). A camera whose size has its photo's aspect is rescaled
//! to the photo's size, focal length and principal point per axis (the lens distortion acts on
//! the normalised image plane and does not change), so that every size the loader derives
//! (`data.downscale`, the pixel budget, eval's) counts from the photos themselves and nothing
//! is rendered above their size. A camera of another aspect is refused, naming both sizes
//! ([`check_photo_size`]).

use std::path::Path;

use anyhow::Result;

use super::capture_frame::CaptureFrame;
use super::dataset_error::DatasetError;
use nerf_core::camera::checks::check_photo_size;
use nerf_core::term::short_number;

/// Rescales every frame's camera to its photo's size on disk (a photo that cannot be read
/// here is left to the image loader, which names it). Returns the one-line note of what was
/// rescaled (`poses_bounds.npy gives 4000×4000 photos, images/ holds 1000×1000: intrinsics
/// scaled by 0.25`), `None` when every camera had its photo's size. `source` names the camera
/// file, `dir` the capture (photo folders are named relative to it).
pub(crate) fn fit_cameras_to_photos(
    dir: &Path,
    source: &str,
    frames: &mut [CaptureFrame],
) -> Result<Option<String>> {
    let mut rescaled = 0;
    let total = frames.len();
    let mut example = None;
    for frame in frames.iter_mut() {
        let Some(photo) = photo_dimensions(&frame.file_path) else {
            continue;
        };
        let camera_size = frame.camera.size;
        if camera_size == (photo.0 as usize, photo.1 as usize) {
            continue;
        }
        check_photo_size(camera_size, photo).map_err(|camera| {
            let message = format!("{}: {camera}", frame.file_path.display());
            DatasetError::Camera { camera, message }
        })?;
        let sx = f64::from(photo.0) / camera_size.0 as f64;
        let sy = f64::from(photo.1) / camera_size.1 as f64;
        let camera = &mut frame.camera;
        camera.focal = [camera.focal[0] * sx, camera.focal[1] * sy];
        camera.principal_point = [
            camera.principal_point[0] * sx,
            camera.principal_point[1] * sy,
        ];
        camera.size = (photo.0 as usize, photo.1 as usize);
        rescaled += 1;
        if example.is_none() {
            example = Some((camera_size, photo, sx, sy, frame.file_path.clone()));
        }
    }
    let Some((camera_size, photo, sx, sy, file)) = example else {
        return Ok(None);
    };
    let folder = file
        .parent()
        .map(|p| p.strip_prefix(dir).unwrap_or(p).display().to_string())
        .filter(|f| !f.is_empty())
        .map_or_else(|| "the capture".to_string(), |f| format!("{f}/"));
    let scale = if (sx - sy).abs() <= 1e-9 * sx.abs() {
        short_number(sx)
    } else {
        format!("{} across, {} down", short_number(sx), short_number(sy))
    };
    let frames = if rescaled == total {
        String::new()
    } else {
        format!(" ({rescaled} of {total} frames)")
    };
    Ok(Some(format!(
        "{source} gives {}×{} photos, {folder} holds {}×{}: intrinsics scaled by {scale}{frames}",
        camera_size.0, camera_size.1, photo.0, photo.1
    )))
}

/// The `(width, height)` a regular image file's header gives; `None` for anything else.
fn photo_dimensions(path: &Path) -> Option<(u32, u32)> {
    // Only a regular file (a FIFO would block the reader): the image loader names the rest.
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return None;
    }
    image::image_dimensions(path).ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;
    use nerf_core::camera::{ColmapCamera, ColmapPose};

    fn frame(dir: &Path, name: &str, photo: (u32, u32), camera: (usize, usize)) -> CaptureFrame {
        let file_path = dir.join(name);
        image::RgbImage::new(photo.0, photo.1)
            .save(&file_path)
            .unwrap();
        let pose = ColmapPose::from_matrix(DMat3::IDENTITY.to_cols_array_2d(), [0.0, 0.0, 1.0]);
        let (w, h) = (camera.0 as f64, camera.1 as f64);
        let params = [w, w, w / 2.0, h / 2.0];
        CaptureFrame {
            file_path,
            camera: ColmapCamera::from_colmap("PINHOLE", &params, camera, pose).unwrap(),
            mask_path: None,
            depth_bounds: None,
        }
    }

    #[test]
    fn cameras_of_larger_photos_are_scaled_to_the_photos_and_other_aspects_refused() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("images")).unwrap();
        let images = dir.path().join("images");
        let mut frames = vec![
            frame(&images, "a.png", (40, 20), (160, 80)),
            frame(&images, "b.png", (40, 20), (40, 20)),
        ];
        let ray = frames[0].camera.direction_at_pixel(160.0, 0.0);
        let note = fit_cameras_to_photos(dir.path(), "poses_bounds.npy", &mut frames)
            .unwrap()
            .unwrap();
        assert_eq!(
            note,
            "poses_bounds.npy gives 160×80 photos, images/ holds 40×20: intrinsics scaled by \
             0.25 (1 of 2 frames)"
        );
        let camera = &frames[0].camera;
        assert_eq!(camera.size, (40, 20));
        assert_eq!(camera.focal, [40.0, 40.0]);
        assert_eq!(camera.principal_point, [20.0, 10.0]);
        // The same ray through the same corner of the photo.
        assert!((camera.direction_at_pixel(40.0, 0.0) - ray).length() < 1e-12);
        assert_eq!(frames[1].camera.size, (40, 20));
        // Cameras of the photos' size: nothing to say.
        assert_eq!(
            fit_cameras_to_photos(dir.path(), "x", &mut frames).unwrap(),
            None
        );
        // Another aspect: refused, naming both sizes.
        let mut frames = vec![frame(&images, "c.png", (40, 20), (160, 160))];
        let err = fit_cameras_to_photos(dir.path(), "x", &mut frames)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("c.png") && err.contains("160x160") && err.contains("40x20"),
            "{err}"
        );
        // A missing photo is left to the image loader.
        let mut frames = vec![frame(&images, "d.png", (40, 20), (160, 80))];
        std::fs::remove_file(&frames[0].file_path).unwrap();
        assert_eq!(
            fit_cameras_to_photos(dir.path(), "x", &mut frames).unwrap(),
            None
        );
        assert_eq!(frames[0].camera.size, (160, 80));
    }
}
