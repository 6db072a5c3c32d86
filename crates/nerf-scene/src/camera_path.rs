//! Camera paths in nerfstudio's `camera_path.json` format (what its viewer exports and
//! `ns-render camera-path` reads), turned into pytorch3d cameras.
//!
//! The fields read (others, such as `keyframes` or `crop`, are ignored):
//!
//! ```json
//! { "camera_type": "perspective", "render_width": 128, "render_height": 128, "fps": 24,
//!   "seconds": 2.0,
//!   "camera_path": [ { "camera_to_world": [16 numbers, row-major 4×4], "fov": 50.0 }, … ] }
//! ```
//!
//! Every entry of `camera_path` is one frame. `camera_to_world` has OpenGL/Blender camera axes
//! (+X right, +Y up, the camera looking along −Z); `fov` is the vertical field of view in
//! degrees (nerfstudio: `f_px = (H/2) / tan(fov/2)` for both axes). The frame rate is `fps`,
//! or, as `ns-render` computes it when `fps` is absent, frames / `seconds`.

use std::path::Path;

use anyhow::{anyhow, bail, ensure, Result};
use serde::Deserialize;

use crate::dataset::{blender_to_pytorch3d, check_rigid};
use nerf_core::camera::PerspectiveCamera;
use nerf_files::bounded_read::read_regular_file;

#[derive(Debug, Deserialize)]
struct CameraPathFile {
    #[serde(default)]
    camera_type: Option<String>,
    render_width: usize,
    render_height: usize,
    #[serde(default)]
    fps: Option<f64>,
    #[serde(default)]
    seconds: Option<f64>,
    camera_path: Vec<PathEntry>,
}

#[derive(Debug, Deserialize)]
struct PathEntry {
    camera_to_world: Vec<f64>,
    fov: f64,
}

/// A camera path: one camera per frame, the image size and the frame rate.
#[derive(Debug, Clone)]
pub struct CameraPath {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Frames per second.
    pub fps: f64,
    /// One pytorch3d camera per frame.
    pub cameras: Vec<PerspectiveCamera>,
}

/// The pytorch3d camera of an OpenGL/Blender camera-to-world matrix `c2w` (`[row][col]`)
/// with vertical field of view `fov_deg` for a `width × height` image.
///
/// Rotation and translation as [`blender_to_pytorch3d`]. On the homework's pixel grid NDC runs
/// over `[−1, 1]` on both axes, so square pixels need `f_y = 1 / tan(fov/2)` and
/// `f_x = f_y · H / W`.
pub(crate) fn camera_from_opengl(
    c2w: [[f64; 4]; 4],
    fov_deg: f64,
    width: usize,
    height: usize,
) -> Result<PerspectiveCamera> {
    ensure!(
        fov_deg.is_finite() && fov_deg > 0.0 && fov_deg < 180.0,
        "fov = {fov_deg} is not a field of view in (0, 180) degrees"
    );
    ensure!(width > 0 && height > 0, "the image size must be positive");
    check_rigid(&c2w)?;
    let mut camera = blender_to_pytorch3d(c2w, fov_deg.to_radians(), width);
    let f_y = camera.focal[1];
    camera.focal = [f_y * height as f64 / width as f64, f_y];
    camera.validate()?;
    Ok(camera)
}

/// Largest camera path file read (a 3600-frame path is about 1 MB).
pub(crate) const MAX_CAMERA_PATH_BYTES: u64 = 64 << 20;

/// Reads a `camera_path.json` file; errors name the file and, for a malformed one, the key.
/// The file must be a regular file of at most `MAX_CAMERA_PATH_BYTES`.
pub fn read_camera_path(path: &Path) -> Result<CameraPath> {
    let bytes = read_regular_file(path, "camera path", MAX_CAMERA_PATH_BYTES)?;
    parse_camera_path(&bytes).map_err(|e| anyhow!("camera path {}: {e}", path.display()))
}

/// Parses the text of a `camera_path.json`; see [`read_camera_path`].
pub fn parse_camera_path(bytes: &[u8]) -> Result<CameraPath> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let file: CameraPathFile =
        serde_path_to_error::deserialize(&mut de).map_err(|e| anyhow!("{e}"))?;
    if let Some(kind) = file.camera_type.as_deref().filter(|k| *k != "perspective") {
        bail!("camera_type {kind:?}: only perspective cameras are rendered");
    }
    let (w, h) = (file.render_width, file.render_height);
    ensure!(
        w > 0 && h > 0,
        "render_width and render_height must be positive"
    );
    ensure!(!file.camera_path.is_empty(), "camera_path has no cameras");
    let n = file.camera_path.len() as f64;
    let fps = match (file.fps, file.seconds) {
        (Some(fps), _) => fps,
        (None, Some(seconds)) => n / seconds,
        (None, None) => bail!("neither fps nor seconds: the frame rate is unknown"),
    };
    ensure!(
        fps.is_finite() && fps > 0.0,
        "the frame rate must be positive (fps {fps})"
    );
    let cameras = file
        .camera_path
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let m = &entry.camera_to_world;
            ensure!(
                m.len() == 16,
                "camera_path[{i}].camera_to_world has {} numbers, not 16",
                m.len()
            );
            let c2w = std::array::from_fn(|r| std::array::from_fn(|c| m[4 * r + c]));
            camera_from_opengl(c2w, entry.fov, w, h).map_err(|e| anyhow!("camera_path[{i}]: {e}"))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(CameraPath {
        width: w,
        height: h,
        fps,
        cameras,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use nerf_core::camera::look_at_view_transform;

    /// A camera at (0, 0, 4) looking at the origin with +Y up: OpenGL axes right = +X,
    /// up = +Y, back = +Z, so the camera-to-world matrix is a pure translation.
    const AT_Z4: &str = r#"{"camera_type": "perspective", "render_width": 64, "render_height": 32,
        "fps": 12, "seconds": 99, "keyframes": [],
        "camera_path": [{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,4, 0,0,0,1], "fov": 90,
                         "aspect": 2.0}]}"#;

    #[test]
    fn a_hand_written_pose_gives_the_look_at_camera() {
        let path = parse_camera_path(AT_Z4.as_bytes()).unwrap();
        assert_eq!((path.width, path.height, path.fps), (64, 32, 12.0));
        let cam = path.cameras[0];
        let (r, t) = look_at_view_transform(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, DVec3::Y);
        let flat = |m: [[f64; 3]; 3]| m.concat();
        let worst_r = flat(cam.r)
            .iter()
            .zip(flat(r))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let worst_t = cam
            .t
            .iter()
            .zip(t)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            worst_r < 1e-12 && worst_t < 1e-12,
            "R off by {worst_r}, T by {worst_t}"
        );
        // fov 90°: f_y = 1/tan(45°) = 1, and f_x = f_y·H/W = 0.5 for square pixels.
        assert!((cam.focal[1] - 1.0).abs() < 1e-12 && (cam.focal[0] - 0.5).abs() < 1e-12);
        // A point at the top edge of the 90° frustum (y = z·tan 45°) lands on y_ndc = 1; one
        // as far to the right lands on x_ndc = −H/W (NDC +X is left).
        let top = cam.project(DVec3::new(0.0, 1.0, 3.0));
        assert!((top.y - 1.0).abs() < 1e-12 && top.x.abs() < 1e-12);
        let right = cam.project(DVec3::new(1.0, 0.0, 3.0));
        assert!((right.x + 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_rotated_pose_matches_look_at_from_the_side() {
        // Camera at (3, 0, 0) looking at the origin, +Y up: right = −Z, up = +Y, back = +X.
        let json = r#"{"render_width": 8, "render_height": 8, "seconds": 2,
            "camera_path": [{"camera_to_world": [0,0,1,3, 0,1,0,0, -1,0,0,0, 0,0,0,1], "fov": 40},
                            {"camera_to_world": [0,0,1,3, 0,1,0,0, -1,0,0,0, 0,0,0,1], "fov": 40}]}"#;
        let path = parse_camera_path(json.as_bytes()).unwrap();
        assert_eq!(path.fps, 1.0);
        let (r, t) = look_at_view_transform(DVec3::new(3.0, 0.0, 0.0), DVec3::ZERO, DVec3::Y);
        let cam = path.cameras[1];
        assert!((0..3).all(|i| (0..3).all(|j| (cam.r[i][j] - r[i][j]).abs() < 1e-12)));
        assert!((0..3).all(|i| (cam.t[i] - t[i]).abs() < 1e-12));
        let f = 1.0 / 20f64.to_radians().tan();
        assert!(cam.focal.iter().all(|v| (v - f).abs() < 1e-12));
    }

    #[test]
    fn malformed_paths_are_refused_with_their_key() {
        let err = |json: &str| parse_camera_path(json.as_bytes()).unwrap_err().to_string();
        let pose = "[1,0,0,0, 0,1,0,0, 0,0,1,4, 0,0,0,1]";
        let with = |fov: &str, m: &str, extra: &str| {
            format!(
                r#"{{"render_width": 8, "render_height": 8, "fps": 10 {extra}, "camera_path": [{{"camera_to_world": {m}, "fov": {fov}}}]}}"#
            )
        };
        assert!(err(&with("0", pose, "")).contains("fov"));
        assert!(err(&with("180", pose, "")).contains("fov"));
        assert!(err(&with("50", "[1,0,0]", "")).contains("16"));
        assert!(err(&with("50", "[2,0,0,0, 0,1,0,0, 0,0,1,4, 0,0,0,1]", "")).contains("rotation"));
        // A camera 1e300 away sees nothing: refused, naming the entry.
        let far = err(&with("50", "[1,0,0,0, 0,1,0,0, 0,0,1,1e300, 0,0,0,1]", ""));
        assert!(
            far.contains("camera_path[0]") && far.contains("farther"),
            "{far}"
        );
        assert!(err(&with("50", pose, r#", "camera_type": "fisheye""#)).contains("perspective"));
        assert!(
            err(r#"{"render_width": 8, "render_height": 8, "fps": 1, "camera_path": []}"#)
                .contains("no cameras")
        );
        assert!(err(r#"{"render_width": 8, "render_height": 8, "camera_path": [{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,4, 0,0,0,1], "fov": 50}]}"#).contains("frame rate"));
        assert!(err(r#"{"render_width": "x"}"#).contains("render_width"));
    }
}
