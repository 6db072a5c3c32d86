//! True cameras of benchmark captures, to measure what structure from motion recovered
//! ([`nerf_core::camera::alignment`]): each as an image stem, a camera → world rotation in
//! OpenGL camera axes (+x right, +y up, +z backward: nerfstudio's `transform_matrix`) and a
//! centre. Three formats:
//!
//! * a nerfstudio or NeRF-synthetic `transforms*.json` ([`read_transforms`]): 4×4 camera →
//!   world matrices, OpenGL axes;
//! * Middlebury multi-view stereo's `*_par.txt` ([`read_middlebury_par`], e.g. templeRing):
//!   a count, then per image `name k11..k33 r11..r33 t1 t2 t3`, the projection `K·[R t]`
//!   world → camera in OpenCV axes (+y down, +z forward), so the centre is `−Rᵀt`;
//! * Strecha et al.'s `*.camera` files ([`read_strecha_cameras`], e.g. Herz-Jesu-P25), one per
//!   image named `<image>.camera`: K (3 rows), the radial distortion (a row), R camera → world
//!   (3 rows, OpenCV axes), the centre C (a row), the image size.

use std::path::Path;

use anyhow::{bail, Context, Result};
use glam::{DMat3, DVec3};

use nerf_files::bounded_read::read_regular_file;

/// The largest truth file read.
const MAX_BYTES: u64 = 16 << 20;

/// One true camera.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueCamera {
    /// The image's file name without folders and extension (`r_7`, `templeR0001`, `0000`).
    pub stem: String,
    /// Camera → world rotation, OpenGL camera axes.
    pub rotation: DMat3,
    /// The camera centre, world units.
    pub centre: DVec3,
}

/// The stem of an image path or name: no folders, no extension (`images/r_7.jpg` → `r_7`).
pub fn image_stem(name: &str) -> String {
    let file = name.rsplit(['/', '\\']).next().unwrap_or(name);
    match file.rsplit_once('.') {
        Some((stem, ext)) if !stem.is_empty() && ext.chars().all(|c| c.is_ascii_alphanumeric()) => {
            stem.to_string()
        }
        _ => file.to_string(),
    }
}

/// OpenCV camera axes (+y down, +z forward) to OpenGL's: the camera's y and z axes negated.
fn opencv_to_opengl(rotation: DMat3) -> DMat3 {
    DMat3::from_cols(rotation.x_axis, -rotation.y_axis, -rotation.z_axis)
}

/// The text of a truth file, bounded in size.
fn read_text(path: &Path) -> Result<String> {
    let bytes = read_regular_file(path, "camera truth", MAX_BYTES)?;
    String::from_utf8(bytes).with_context(|| format!("{}: not UTF-8 text", path.display()))
}

/// Whitespace-separated numbers of `text`, each finite; the error names `what`.
fn numbers(text: &str, what: &dyn Fn() -> String) -> Result<Vec<f64>> {
    text.split_whitespace()
        .map(|w| match w.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => bail!("{}: {w:?} is not a finite number", what()),
        })
        .collect()
}

/// A rotation from 9 numbers row by row; an error unless it is one to 1e-4.
fn rotation_rows(v: &[f64], what: &dyn Fn() -> String) -> Result<DMat3> {
    let r = DMat3::from_cols_array(&[v[0], v[3], v[6], v[1], v[4], v[7], v[2], v[5], v[8]]);
    let off = (r.transpose() * r - DMat3::IDENTITY).to_cols_array();
    if off.iter().any(|e| e.abs() > 1e-4) || (r.determinant() - 1.0).abs() > 1e-4 {
        bail!("{}: R is not a rotation", what());
    }
    Ok(r)
}

/// The frames of a nerfstudio or NeRF-synthetic `transforms*.json`.
pub fn read_transforms(path: &Path) -> Result<Vec<TrueCamera>> {
    let text = read_text(path)?;
    let json: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let frames = json["frames"]
        .as_array()
        .with_context(|| format!("{}: no frames", path.display()))?;
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let what = || format!("{} frame {i}", path.display());
            let name = f["file_path"]
                .as_str()
                .with_context(|| format!("{}: file_path missing", what()))?;
            let m = &f["transform_matrix"];
            let mut v = [0.0; 12];
            for (k, value) in v.iter_mut().enumerate() {
                *value = m[k / 4][k % 4]
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .with_context(|| format!("{}: transform_matrix is not 4×4 numbers", what()))?;
            }
            let rows = [v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]];
            Ok(TrueCamera {
                stem: image_stem(name),
                rotation: rotation_rows(&rows, &what)?,
                centre: DVec3::new(v[3], v[7], v[11]),
            })
        })
        .collect()
}

/// The cameras of a Middlebury `*_par.txt` (see the module).
pub fn read_middlebury_par(path: &Path) -> Result<Vec<TrueCamera>> {
    let text = read_text(path)?;
    let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
    let count: usize = lines
        .next()
        .and_then(|l| l.parse().ok())
        .with_context(|| format!("{}: the first line is not a camera count", path.display()))?;
    let cameras: Vec<TrueCamera> = lines
        .enumerate()
        .map(|(i, line)| {
            let what = || format!("{} camera {}", path.display(), i + 1);
            let (name, rest) = line
                .split_once(char::is_whitespace)
                .with_context(|| format!("{}: no numbers", what()))?;
            let v = numbers(rest, &what)?;
            if v.len() != 21 {
                bail!("{}: {} numbers, not 21 (K, R, t)", what(), v.len());
            }
            let world_to_camera = rotation_rows(&v[9..18], &what)?;
            let t = DVec3::new(v[18], v[19], v[20]);
            Ok(TrueCamera {
                stem: image_stem(name),
                rotation: opencv_to_opengl(world_to_camera.transpose()),
                centre: -(world_to_camera.transpose() * t),
            })
        })
        .collect::<Result<_>>()?;
    if cameras.len() != count {
        bail!(
            "{}: says {count} cameras but holds {}",
            path.display(),
            cameras.len()
        );
    }
    Ok(cameras)
}

/// The cameras of the `*.camera` files in `dir` (see the module), sorted by stem.
pub fn read_strecha_cameras(dir: &Path) -> Result<Vec<TrueCamera>> {
    let entries =
        std::fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))?;
    let mut cameras = Vec::new();
    for entry in entries {
        let path = entry
            .with_context(|| format!("cannot list {}", dir.display()))?
            .path();
        let Some(image) = path
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.strip_suffix(".camera"))
        else {
            continue;
        };
        let what = || path.display().to_string();
        let v = numbers(&read_text(&path)?, &what)?;
        if v.len() < 24 {
            bail!(
                "{}: {} numbers, not K, distortion, R, C and size",
                what(),
                v.len()
            );
        }
        cameras.push(TrueCamera {
            stem: image_stem(image),
            rotation: opencv_to_opengl(rotation_rows(&v[12..21], &what)?),
            centre: DVec3::new(v[21], v[22], v[23]),
        });
    }
    if cameras.is_empty() {
        bail!("no .camera files in {}", dir.display());
    }
    cameras.sort_by(|a, b| a.stem.cmp(&b.stem));
    Ok(cameras)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A world → camera rotation (OpenCV axes) that is not symmetric.
    fn world_to_camera() -> DMat3 {
        DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -1.2, 2.5)
    }

    fn rows(r: DMat3) -> String {
        let c = r.transpose().to_cols_array();
        c.iter().map(|v| format!("{v:.17} ")).collect()
    }

    #[test]
    fn middlebury_centres_are_minus_r_transpose_t() {
        let dir = tempfile::tempdir().unwrap();
        let r = world_to_camera();
        let centre = DVec3::new(0.1, -0.4, 0.55);
        let t = -(r * centre);
        let k = "1520.4 0 302.3 0 1525.9 246.9 0 0 1 ";
        let line = format!("a/temple0001.png {k}{}{} {} {}\n", rows(r), t.x, t.y, t.z);
        let path = dir.path().join("t_par.txt");
        std::fs::write(&path, format!("1\n{line}")).unwrap();
        let cameras = read_middlebury_par(&path).unwrap();
        assert_eq!(cameras[0].stem, "temple0001");
        assert!((cameras[0].centre - centre).length() < 1e-12);
        // The camera looks along +z in OpenCV axes, −z in OpenGL's: the same world direction.
        let forward = r.transpose() * DVec3::Z;
        assert!((cameras[0].rotation * DVec3::NEG_Z - forward).length() < 1e-12);
        std::fs::write(&path, format!("2\n{line}")).unwrap();
        let e = read_middlebury_par(&path).unwrap_err();
        assert!(e.to_string().contains("says 2 cameras"), "{e}");
        std::fs::write(&path, "1\nx.png 1 2 3\n").unwrap();
        assert!(read_middlebury_par(&path).is_err());
    }

    #[test]
    fn strecha_cameras_hold_camera_to_world_and_the_centre() {
        let dir = tempfile::tempdir().unwrap();
        let camera_to_world = world_to_camera().transpose();
        let text = format!(
            "2759.48 0 1520.69\n0 2764.16 1006.81\n0 0 1\n0 0 0\n{}\n1.9 -5.3 10.1\n3072 2048\n",
            rows(camera_to_world)
        );
        std::fs::write(dir.path().join("0003.jpg.camera"), text).unwrap();
        std::fs::write(dir.path().join("notes.txt"), "not a camera").unwrap();
        let cameras = read_strecha_cameras(dir.path()).unwrap();
        assert_eq!(cameras.len(), 1);
        assert_eq!(cameras[0].stem, "0003");
        assert_eq!(cameras[0].centre, DVec3::new(1.9, -5.3, 10.1));
        let x = cameras[0].rotation * DVec3::X;
        assert!((x - camera_to_world * DVec3::X).length() < 1e-12);
        let y = cameras[0].rotation * DVec3::Y;
        assert!((y + camera_to_world * DVec3::Y).length() < 1e-12);
        std::fs::write(dir.path().join("0004.jpg.camera"), "1 2 3").unwrap();
        assert!(read_strecha_cameras(dir.path()).is_err());
    }

    #[test]
    fn stems_drop_folders_and_extensions() {
        assert_eq!(image_stem("images/r_7.jpg"), "r_7");
        assert_eq!(image_stem("./train/r_7"), "r_7");
        assert_eq!(image_stem("0000.jpg"), "0000");
        assert_eq!(image_stem("frame_00012.png"), "frame_00012");
    }
}
