//! `transforms_{split}.json`: the NeRF-synthetic release's camera file, read into [`Frame`]s
//! whose Blender cameras are converted to pytorch3d's conventions.

use std::path::{Component, Path, PathBuf};

use anyhow::Result;
use glam::{DMat3, DMat4};
use serde::Deserialize;

use super::scene_format::SceneFormat;
pub use super::split::Split;
use super::{DatasetError, DOWNLOAD_HINT};
use nerf_core::camera::PerspectiveCamera;
use nerf_core::camera::CameraError;
use nerf_core::camera::Camera;
use nerf_files::bounded_read::read_regular_file;

/// The NeRF-synthetic release: a folder with `transforms_{split}.json` files, read split by
/// split ([`read_blender_split`]) rather than as a capture.
pub(crate) const BLENDER: SceneFormat = SceneFormat {
    key: "blender",
    name: "NeRF-synthetic (transforms_{split}.json)",
    marks: "transforms_{train,val,test}.json (NeRF-synthetic)",
    holds: |dir| Split::ALL.iter().any(|s| s.transforms_path(dir).is_file()),
    listing: |dir| Split::Train.transforms_path(dir),
    read: None,
};

/// One view of a split: its image and its camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Path of the RGBA PNG: `data_dir` joined with the JSON's `file_path` (leading `./`
    /// dropped), with `.png` appended when the JSON gives no extension.
    pub file_path: PathBuf,
    /// The view's camera: pytorch3d's pinhole for the NeRF-synthetic scenes, COLMAP's
    /// conventions (with distortion) for captures.
    pub camera: Camera,
    /// The frame's mask (`super::frame_mask`), when it has one (captures only).
    pub mask_path: Option<PathBuf>,
}

/// Converts a Blender camera-to-world matrix to a pytorch3d camera.
///
/// * `c2w`: 4×4 camera-to-world matrix, `[row][col]`; columns 0–2 of its upper 3×3 block are
///   the Blender camera's +X (right), +Y (up) and +Z (backwards, the camera looks along −Z) in
///   world coordinates, column 3 is the camera centre.
/// * `camera_angle_x`: horizontal field of view in radians.
/// * `width`: image width in pixels, for the pixel focal length `f_px = (W/2) / tan(fov/2)`.
///
/// pytorch3d's axes are Blender's with X and Z flipped (+X left, +Y up, +Z forward), and `R`
/// holds them as columns: for a rigid `c2w`, `R = c2w[:3, :3] · diag(−1, 1, −1)` and
/// `T = −Rᵀ · centre`. The matrix is inverted rather than transposed — `w2c = c2w⁻¹`,
/// `Rᵀ = diag(−1, 1, −1) · w2c[:3, :3]`, `T = diag(−1, 1, −1) · w2c[:3, 3]` — which is the
/// same for an exact rotation and, for the float32-rounded matrices of the release, reproduces
/// the reference `cameras_pytorch3d.json` about ten times more closely (5e-7 instead of 5e-6 in
/// `T`). A singular `c2w` gives non-finite values, which [`PerspectiveCamera::validate`]
/// rejects.
///
/// The NDC focal length is `f_px / (W/2) = 1 / tan(camera_angle_x / 2)` (≈ 2.7778 for lego),
/// independent of `width`. The same value is used for y, which is right for square source
/// images (NeRF-synthetic renders are 800×800) under the homework's pixel grid, whose y runs
/// over [−1, 1] too, whatever size the images are resized to. The principal point is zero.
pub(crate) fn blender_to_pytorch3d(
    c2w: [[f64; 4]; 4],
    camera_angle_x: f64,
    width: usize,
) -> PerspectiveCamera {
    let half_width = width.max(1) as f64 / 2.0;
    let focal_px = half_width / (camera_angle_x / 2.0).tan();
    let focal_ndc = focal_px / half_width;
    // glam takes columns, so transposing the row-major array gives the matrix itself.
    let c2w_mat = DMat4::from_cols_array_2d(&c2w).transpose();
    let w2c = c2w_mat.inverse();
    // Blender view → pytorch3d view flips X and Z.
    let flip = [-1.0, 1.0, -1.0];
    let mut r = [[0.0; 3]; 3];
    let mut t = [0.0; 3];
    for j in 0..3 {
        // Row j of the world-to-view rotation (w2c) is column j of R.
        let w2c_row = w2c.row(j);
        for (i, row) in r.iter_mut().enumerate() {
            row[j] = flip[j] * w2c_row[i];
        }
        t[j] = flip[j] * w2c_row[3];
    }
    PerspectiveCamera::new(r, t, focal_ndc)
}

/// `transforms_{split}.json` as written by the NeRF-synthetic release (extra keys such as
/// `rotation` are ignored).
#[derive(Debug, Deserialize)]
struct TransformsFile {
    camera_angle_x: f64,
    frames: Vec<TransformsFrame>,
}

#[derive(Debug, Deserialize)]
struct TransformsFrame {
    file_path: String,
    transform_matrix: [[f64; 4]; 4],
}

/// Farthest a camera may be from the origin, in scene units (the NeRF-synthetic cameras are
/// 4 away; a camera 1e300 away would see nothing and be scored as a black view).
pub(crate) const MAX_CAMERA_DISTANCE: f64 = 1e4;

/// Largest `transforms_*.json` read (the lego scene's are 60 KB).
pub(crate) const MAX_TRANSFORMS_BYTES: u64 = 64 << 20;

/// Checks that the upper 3×3 block of a camera-to-world matrix is a rotation (orthonormal,
/// determinant +1, to 1e-3), the bottom row is `(0, 0, 0, 1)` and the camera centre is within
/// [`MAX_CAMERA_DISTANCE`] of the origin; the error is a [`CameraError::Pose`].
pub(crate) fn check_rigid(c2w: &[[f64; 4]; 4]) -> Result<(), CameraError> {
    let refuse = |message: String| Err(CameraError::Pose { message });
    if c2w.iter().flatten().any(|v| !v.is_finite()) {
        return refuse("transform_matrix has a non-finite entry".to_string());
    }
    let centre = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let distance = centre.iter().map(|v| v * v).sum::<f64>().sqrt();
    if distance > MAX_CAMERA_DISTANCE {
        return refuse(format!(
            "transform_matrix puts the camera {distance:.3e} from the origin, farther than {MAX_CAMERA_DISTANCE:e} scene units"
        ));
    }
    let bottom = c2w[3];
    if bottom
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(a, b)| (a - b).abs() > 1e-6)
    {
        return refuse(format!(
            "transform_matrix bottom row is {bottom:?}, expected [0, 0, 0, 1]"
        ));
    }
    let m = DMat3::from_cols_array_2d(&[
        [c2w[0][0], c2w[1][0], c2w[2][0]],
        [c2w[0][1], c2w[1][1], c2w[2][1]],
        [c2w[0][2], c2w[1][2], c2w[2][2]],
    ]);
    let off = (m.transpose() * m - DMat3::IDENTITY).abs();
    let worst = off
        .x_axis
        .max_element()
        .max(off.y_axis.max_element())
        .max(off.z_axis.max_element());
    if worst > 1e-3 || m.determinant() <= 0.0 {
        return refuse(format!("transform_matrix rotation block is not a rotation (|RᵀR − I| = {worst:.2e}, det = {:.4})", m.determinant()));
    }
    Ok(())
}

/// `data_dir` joined with a JSON `file_path`, leading `./` dropped, `.png` appended when it has
/// no extension.
fn image_path(data_dir: &Path, file_path: &str) -> PathBuf {
    let relative: PathBuf = Path::new(file_path)
        .components()
        .filter(|c| !matches!(c, Component::CurDir))
        .collect();
    let mut path = data_dir.join(relative);
    if path.extension().is_none() {
        path.set_extension("png");
    }
    path
}

/// Reads the NeRF-synthetic `data_dir/transforms_{split}.json`: one [`Frame`] per entry of `frames`, in file order.
///
/// Errors (one line, naming the file) when the directory or the file is missing (with
/// [`DOWNLOAD_HINT`]), when the JSON does not parse (with the offending key path), or when a
/// frame's matrix or the field of view is unusable. Images are not opened here. The errors
/// ([`DatasetError`]): [`DatasetError::NoDataset`] for a missing directory,
/// [`DatasetError::MissingFile`] for a missing transforms file, and those of [`parse_split`].
pub(crate) fn read_blender_split(data_dir: &Path, split: Split) -> Result<Vec<Frame>, DatasetError> {
    if !data_dir.is_dir() {
        let why = match data_dir.exists() {
            true => "is a file, not a directory",
            false => "does not exist",
        };
        let message = format!(
            "dataset directory {} {why}; {DOWNLOAD_HINT}",
            data_dir.display()
        );
        return Err(DatasetError::no_dataset(data_dir, message));
    }
    let path = split.transforms_path(data_dir);
    if !path.exists() {
        let message = format!(
            "cannot read {}: it does not exist; {DOWNLOAD_HINT}",
            path.display()
        );
        return Err(DatasetError::missing_file(&path, message));
    }
    let bytes = read_regular_file(&path, "dataset file", MAX_TRANSFORMS_BYTES)
        .map_err(DatasetError::Other)?;
    parse_split(&bytes, data_dir, &path)
}

/// Parses the text of a `transforms_{split}.json` (read from `path`, named in errors) into
/// frames whose image paths are relative to `data_dir`; see [`super::read_split`]. Errors:
/// [`DatasetError::Metadata`] for JSON that does not parse, an unusable field of view or no
/// frames, [`DatasetError::Camera`] for a frame's camera.
pub fn parse_split(bytes: &[u8], data_dir: &Path, path: &Path) -> Result<Vec<Frame>, DatasetError> {
    let metadata = |message: String| DatasetError::metadata(path, message);
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let file: TransformsFile = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| metadata(format!("cannot parse {}: {e}", path.display())))?;
    let fov = file.camera_angle_x;
    // The NDC focal length 1/tan(fov/2) within the viewer's bounds, 1e-3 to 1e3: a field of
    // view of 1e-300 rad would otherwise score a black view instead of being refused.
    let focal = 1.0 / (fov / 2.0).tan();
    if !(fov.is_finite()
        && fov > 0.0
        && fov < std::f64::consts::PI
        && (1e-3..=1e3).contains(&focal))
    {
        return Err(metadata(format!(
            "{}: camera_angle_x = {fov} is not a usable field of view (between 0.002 and 3.139 radians: an NDC focal length from 1e-3 to 1e3)",
            path.display()
        )));
    }
    if file.frames.is_empty() {
        return Err(metadata(format!("{}: no frames", path.display())));
    }
    file.frames
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let context = |camera: CameraError| {
                let message = format!(
                    "{}: frame {i} ({}): {camera}",
                    path.display(),
                    entry.file_path
                );
                DatasetError::Camera { camera, message }
            };
            check_rigid(&entry.transform_matrix).map_err(context)?;
            // The pixel width only enters f_px and cancels in the NDC focal length; the NeRF
            // renders are 800 wide.
            let camera = blender_to_pytorch3d(entry.transform_matrix, fov, 800);
            camera.validate().map_err(context)?;
            Ok(Frame {
                file_path: image_path(data_dir, &entry.file_path),
                camera: camera.into(),
                mask_path: None,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::read_split;
    use crate::dataset::test_lego_dir;
    use glam::DVec3;
    use nerf_core::camera::look_at_rotation;
    use nerf_core::rays::ray_through_ndc;

    fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
        (a - b).abs().max_element() <= tol
    }

    /// A Blender camera at `centre` with the given right/up/back axes (world space).
    fn c2w(right: DVec3, up: DVec3, back: DVec3, centre: DVec3) -> [[f64; 4]; 4] {
        let mut m = [[0.0; 4]; 4];
        for (i, row) in m.iter_mut().take(3).enumerate() {
            *row = [right[i], up[i], back[i], centre[i]];
        }
        m[3] = [0.0, 0.0, 0.0, 1.0];
        m
    }

    #[test]
    fn blender_camera_on_z_axis_converts_by_hand() {
        // Blender camera at (0, 0, 4) with identity rotation looks along −Z at the origin.
        let m = c2w(DVec3::X, DVec3::Y, DVec3::Z, DVec3::new(0.0, 0.0, 4.0));
        let fov = 2.0 * (0.5f64).atan();
        let cam = blender_to_pytorch3d(m, fov, 400);
        let expected_r = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]];
        assert_eq!(cam.r, expected_r);
        assert_eq!(cam.t, [0.0, 0.0, 4.0]);
        assert!((cam.focal[0] - 2.0).abs() < 1e-12 && cam.focal[0] == cam.focal[1]);
        assert_eq!(cam.principal_point, [0.0, 0.0]);
        assert!(close(cam.center(), DVec3::new(0.0, 0.0, 4.0), 1e-12));
        // The origin is straight ahead at depth 4.
        assert!(close(
            cam.project(DVec3::ZERO),
            DVec3::new(0.0, 0.0, 4.0),
            1e-12
        ));
        // Blender's right (+X world) is on the left of NDC's +X, i.e. negative x_ndc; up stays up.
        assert!(cam.project(DVec3::new(0.5, 0.0, 0.0)).x < 0.0);
        assert!(cam.project(DVec3::new(0.0, 0.5, 0.0)).y > 0.0);
    }

    #[test]
    fn inverse_equals_transpose_formula_for_exact_rotations() {
        // An arbitrary exact rotation: Blender axes from a look-at frame.
        let centre = DVec3::new(1.5, -2.0, 3.0);
        let r = look_at_rotation(centre, DVec3::new(0.2, 0.1, -0.3), DVec3::Z);
        let axis = |j: usize| DVec3::new(r[0][j], r[1][j], r[2][j]);
        let m = c2w(-axis(0), axis(1), -axis(2), centre);
        let cam = blender_to_pytorch3d(m, 0.7, 800);
        for (i, (r_row, m_row)) in cam.r.iter().zip(&m).enumerate() {
            for (j, (r_ij, m_ij)) in r_row.iter().zip(m_row).enumerate() {
                let flip = if j == 1 { 1.0 } else { -1.0 };
                assert!((r_ij - flip * m_ij).abs() < 1e-12, "R[{i}][{j}]");
            }
        }
        // T = −Rᵀ·centre.
        let t = -(DMat3::from_cols_array_2d(&cam.r) * centre);
        assert!(close(DVec3::from_array(cam.t), t, 1e-12));
        assert!(close(cam.center(), centre, 1e-12));
    }

    #[test]
    fn split_names_round_trip() {
        for split in Split::ALL {
            assert_eq!(split.name().parse::<Split>().unwrap(), split);
        }
        assert!("training".parse::<Split>().is_err());
    }

    #[test]
    fn image_paths_drop_dot_and_add_png() {
        let dir = Path::new("/data/lego");
        assert_eq!(
            image_path(dir, "./train/r_0"),
            PathBuf::from("/data/lego/train/r_0.png")
        );
        assert_eq!(
            image_path(dir, "test/r_3.png"),
            PathBuf::from("/data/lego/test/r_3.png")
        );
    }

    #[test]
    fn all_cameras_match_the_pytorch3d_reference() {
        let Some(dir) = test_lego_dir() else { return };
        let reference_path = dir.join("cameras_pytorch3d.json");
        let Ok(text) = std::fs::read_to_string(&reference_path) else {
            eprintln!("skipping: {} not found", reference_path.display());
            return;
        };
        let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
        let frames: Vec<Frame> = Split::ALL
            .into_iter()
            .flat_map(|split| read_blender_split(&dir, split).unwrap())
            .collect();
        assert_eq!(frames.len(), 400);
        let number = |v: &serde_json::Value| v.as_f64().unwrap();
        let (mut dr, mut dt, mut df) = (0.0f64, 0.0f64, 0.0f64);
        for (k, frame) in frames.iter().enumerate() {
            let cam = frame.camera.pinhole().expect("a NeRF-synthetic frame");
            let r = &reference["R"][k];
            for i in 0..3 {
                for j in 0..3 {
                    dr = dr.max((cam.r[i][j] - number(&r[i][j])).abs());
                }
                dt = dt.max((cam.t[i] - number(&reference["T"][k][i])).abs());
            }
            for i in 0..2 {
                df = df.max((cam.focal[i] - number(&reference["focal_length"][k][i])).abs());
                let p = number(&reference["principal_point"][k][i]);
                assert_eq!(cam.principal_point[i], p, "frame {k}");
            }
        }
        eprintln!("max |ΔR| = {dr:.3e}, max |ΔT| = {dt:.3e}, max |Δfocal| = {df:.3e}");
        assert!(dr < 1e-5 && dt < 1e-5 && df < 1e-5);
    }

    #[test]
    fn central_ray_follows_the_blender_view_direction() {
        let Some(dir) = test_lego_dir() else { return };
        let text = std::fs::read_to_string(Split::Test.transforms_path(&dir)).unwrap();
        let file: TransformsFile = serde_json::from_str(&text).unwrap();
        let frames = read_split(&dir, Split::Test).unwrap();
        for (entry, frame) in file.frames.iter().zip(&frames).step_by(17) {
            let m = entry.transform_matrix;
            let look = -DVec3::new(m[0][2], m[1][2], m[2][2]).normalize();
            let centre = DVec3::new(m[0][3], m[1][3], m[2][3]);
            let (origin, direction) = ray_through_ndc(&frame.camera, 0.0, 0.0);
            // The JSON matrices are float32 values, orthonormal to about 1e-7.
            assert!(close(origin, centre, 1e-5), "{origin} vs {centre}");
            assert!(close(direction, look, 1e-6), "{direction} vs {look}");
        }
    }

    #[test]
    fn bad_json_names_the_file_and_key() {
        let (dir, path) = nerf_files::test_files::temp_file("transforms_train.json");
        std::fs::write(
            &path,
            r#"{"camera_angle_x": 0.69, "frames": [{"file_path": "./train/r_0",
                "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1]]}]}"#,
        )
        .unwrap();
        let err = read_split(dir.path(), Split::Train)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(err.contains("transforms_train.json"), "{err}");
        assert!(err.contains("frames[0].transform_matrix"), "{err}");
        // A matrix that is no rotation is rejected with the frame named.
        std::fs::write(
            &path,
            r#"{"camera_angle_x": 0.69, "frames": [{"file_path": "./train/r_7",
                "transform_matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}"#,
        )
        .unwrap();
        let err = read_split(dir.path(), Split::Train)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(
            err.contains("transforms_train.json") && err.contains("r_7"),
            "{err}"
        );
        // A field of view so narrow (or so wide) that the focal length is absurd is refused.
        for fov in ["1e-300", "1e-4", "3.1415"] {
            std::fs::write(
                &path,
                format!(
                    r#"{{"camera_angle_x": {fov}, "frames": [{{"file_path": "./train/r_7",
                    "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}}]}}"#
                ),
            )
            .unwrap();
            let err = read_split(dir.path(), Split::Train)
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("camera_angle_x") && err.contains("focal"),
                "{fov}: {err}"
            );
        }
        // A valid file gives frames with joined paths and converted cameras.
        std::fs::write(
            &path,
            r#"{"camera_angle_x": 0.9272952180016122, "frames": [{"file_path": "./train/r_7",
                "rotation": 0.1,
                "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}"#,
        )
        .unwrap();
        let frames = read_split(dir.path(), Split::Train).unwrap();
        assert_eq!(frames.len(), 1);
        assert_eq!(
            frames[0].file_path,
            dir.path().join("train").join("r_7.png")
        );
        let camera = frames[0].camera.pinhole().unwrap();
        assert_eq!(camera.t, [0.0, 0.0, 4.0]);
        assert!((camera.focal[0] - 2.0).abs() < 1e-12);
    }
}
