//! A Middlebury multi-view stereo set (Seitz et al. 2006: templeRing, dinoRing, …) as a COLMAP
//! text capture that `nerf train --data-dir` reads: `OUT/images/` (copies of the photos) and
//! `OUT/sparse/0/{cameras,images,points3D}.txt` with the set's calibrated cameras.
//!
//! The set's `*_par.txt` holds one line per photo, `name k11 … k33 r11 … r33 t1 t2 t3`: the
//! projection `K [R t]`, world to camera in OpenCV axes (x right, y down, z forward), pixel
//! origin at the top-left corner. COLMAP's text model has the same world → camera pose
//! (`R` as the quaternion `qw qx qy qz`, then `t`) and a `PINHOLE` camera `fx fy cx cy` per
//! photo. COLMAP puts the centre of the top-left pixel at (0.5, 0.5); the set's K is taken to
//! do the same (its convention for pixel centres is not stated; half a pixel at 640×480).
//! Photos the set stores turned by 180° need nothing: their calibration is of the photo as
//! stored.
//!
//! **Photos stood upright.** The gantry's photos are 640×480 and show the object lying on its
//! side; a copy whose photos were turned by 90° to stand upright (480×640, as in
//! `../shared/data/real/temple_ring`) no longer fits the calibration. Such a photo (taller than
//! wide) gets its camera turned with it: the set's `*_ang.txt` gives each photo's latitude,
//! and Middlebury's negative-latitude photos are the positive ones turned by 180° (its
//! README), so standing them upright turns them the other way: a negative latitude is turned
//! counter-clockwise (the photo's new `x` is the old `y`), a positive one clockwise. The
//! cameras `nerf process` recovers from the temple ring's photos agree: each calibrated
//! camera is a quarter turn about the optical axis from COLMAP's, one way for the negative
//! latitudes and the other for the positive ones (measured:
//! docs/own-scene.md#photos-stood-upright).
//!
//! Run: `cargo run --release --example middlebury_capture -- SET_DIR OUT`, e.g.
//! `SET_DIR = ../shared/data/real/temple_ring` (it holds `templeR_par.txt` and `images/`, or
//! the photos beside the file as the original download has them).

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use glam::{DMat3, DQuat, DVec3};

/// One photo's calibration: file name, K (row-major), R (row-major), t.
struct Calibration {
    name: String,
    k: [f64; 9],
    r: [f64; 9],
    t: [f64; 3],
}

/// The `*_par.txt` file of `dir` (exactly one).
fn par_file(dir: &Path) -> Result<PathBuf> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))? {
        let path = entry?.path();
        if path.to_string_lossy().ends_with("_par.txt") {
            found.push(path);
        }
    }
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => bail!("{}: no *_par.txt camera file", dir.display()),
        _ => bail!("{}: several *_par.txt files", dir.display()),
    }
}

/// How a stored photo is turned against the photo its calibration describes.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Turn {
    /// Stored as calibrated.
    None,
    /// Turned by 90° counter-clockwise: pixel `(u, v)` of the calibrated `W × H` photo is
    /// `(v, W − u)` of the stored `H × W` one.
    CounterClockwise,
    /// Turned by 90° clockwise: pixel `(u, v)` is `(H − v, u)` of the stored photo.
    Clockwise,
}

impl Turn {
    /// The camera of the stored photo, from the calibrated `K` (row-major) and world → camera
    /// `R` (row-major) and `t`, the stored photo being `width × height`: `[fx, fy, cx, cy]`,
    /// `R` and `t`. The turn `Q` about the optical axis maps calibrated camera coordinates to
    /// the stored photo's (`R' = Q R`, `t' = Q t`), and the intrinsics follow the pixels.
    fn camera(self, c: &Calibration, (width, height): (f64, f64)) -> ([f64; 4], DMat3, DVec3) {
        let r = DMat3::from_cols_array(&c.r).transpose();
        let t = DVec3::from_array(c.t);
        let [fx, fy, cx, cy] = [c.k[0], c.k[4], c.k[2], c.k[5]];
        let (intrinsics, q) = match self {
            Turn::None => ([fx, fy, cx, cy], DMat3::IDENTITY),
            // New x = old y, new y = −old x; the calibrated photo was `height` wide.
            Turn::CounterClockwise => (
                [fy, fx, cy, height - cx],
                DMat3::from_cols(DVec3::new(0.0, -1.0, 0.0), DVec3::X, DVec3::Z),
            ),
            // New x = −old y, new y = old x; the calibrated photo was `width` tall.
            Turn::Clockwise => (
                [fy, fx, width - cy, cx],
                DMat3::from_cols(DVec3::Y, DVec3::new(-1.0, 0.0, 0.0), DVec3::Z),
            ),
        };
        (intrinsics, q * r, q * t)
    }
}

/// Each photo's latitude by name, from the set's `*_ang.txt` (`lat lon name` a line), when
/// the set has one.
fn latitudes(dir: &Path) -> Result<Option<std::collections::HashMap<String, f64>>> {
    let Some(path) = std::fs::read_dir(dir)
        .with_context(|| format!("cannot list {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.to_string_lossy().ends_with("_ang.txt"))
    else {
        return Ok(None);
    };
    let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
    let mut out = std::collections::HashMap::new();
    for (i, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let latitude = match fields[..] {
            [lat, _, _] => lat.parse::<f64>().ok().filter(|v| v.is_finite()),
            _ => None,
        };
        let latitude = latitude.with_context(|| {
            format!("{} line {}: expected `lat lon name`", path.display(), i + 1)
        })?;
        out.insert(fields[2].to_string(), latitude);
    }
    Ok(Some(out))
}

/// The calibrations of a `*_par.txt` file (its first line is the photo count).
fn read_par(path: &Path) -> Result<Vec<Calibration>> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let count: usize = lines
        .next()
        .context("empty camera file")?
        .trim()
        .parse()
        .with_context(|| format!("{}: the first line is not a photo count", path.display()))?;
    let mut out = Vec::with_capacity(count.min(100_000));
    for (i, line) in lines.enumerate() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        ensure!(
            fields.len() == 22,
            "{} line {}: expected a name and 21 numbers, got {} fields",
            path.display(),
            i + 2,
            fields.len()
        );
        let v: Vec<f64> = fields[1..]
            .iter()
            .map(|f| f.parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .with_context(|| format!("{} line {}: not a number", path.display(), i + 2))?;
        ensure!(
            v.iter().all(|x| x.is_finite()),
            "{} line {}: a value is not finite",
            path.display(),
            i + 2
        );
        out.push(Calibration {
            name: fields[0].to_string(),
            k: std::array::from_fn(|j| v[j]),
            r: std::array::from_fn(|j| v[9 + j]),
            t: std::array::from_fn(|j| v[18 + j]),
        });
    }
    ensure!(
        out.len() == count,
        "{}: the first line says {count} photos, {} follow",
        path.display(),
        out.len()
    );
    Ok(out)
}

/// Writes `text` to `path` by way of a temporary file beside it.
fn write_atomically(path: &Path, text: &str) -> Result<()> {
    let tmp = path.with_extension("txt.tmp");
    std::fs::write(&tmp, text).with_context(|| tmp.display().to_string())?;
    std::fs::rename(&tmp, path).with_context(|| path.display().to_string())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [set, out] = &args[..] else {
        bail!("usage: middlebury_capture SET_DIR OUT");
    };
    let (set, out) = (Path::new(set), Path::new(out));
    let calibrations = read_par(&par_file(set)?)?;
    let latitudes = latitudes(set)?;
    let photos = if set.join("images").is_dir() {
        set.join("images")
    } else {
        set.to_path_buf()
    };
    ensure!(
        !out.join("sparse").exists(),
        "{} already holds sparse/: choose another OUT",
        out.display()
    );
    let sparse = out.join("sparse").join("0");
    std::fs::create_dir_all(&sparse).with_context(|| sparse.display().to_string())?;
    std::fs::create_dir_all(out.join("images"))?;
    let mut cameras = String::from("# CAMERA_ID MODEL WIDTH HEIGHT fx fy cx cy\n");
    let mut images = String::from("# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n");
    let mut turned = 0;
    for (i, c) in calibrations.iter().enumerate() {
        let src = photos.join(&c.name);
        let (w, h) = image::image_dimensions(&src)
            .with_context(|| format!("cannot read photo {}", src.display()))?;
        std::fs::copy(&src, out.join("images").join(&c.name))
            .with_context(|| format!("cannot copy {}", src.display()))?;
        ensure!(
            c.k[1] == 0.0 && c.k[3] == 0.0 && c.k[6] == 0.0 && c.k[7] == 0.0 && c.k[8] == 1.0,
            "{}: K is not a pinhole matrix (skew or a bad last row)",
            c.name
        );
        let turn = if h <= w {
            Turn::None
        } else {
            let latitude = latitudes
                .as_ref()
                .and_then(|l| l.get(&c.name))
                .with_context(|| {
                    format!(
                        "{} is {w}x{h}, stood upright from the gantry's landscape photo: its \
                     latitude in the set's *_ang.txt tells which way it was turned, and there \
                     is none for it",
                        c.name
                    )
                })?;
            if *latitude < 0.0 {
                Turn::CounterClockwise
            } else {
                Turn::Clockwise
            }
        };
        turned += usize::from(turn != Turn::None);
        let ([fx, fy, cx, cy], r, t) = turn.camera(c, (f64::from(w), f64::from(h)));
        let id = i + 1;
        cameras += &format!("{id} PINHOLE {w} {h} {fx} {fy} {cx} {cy}\n");
        ensure!(
            (r.determinant() - 1.0).abs() < 1e-3,
            "{}: R is not a rotation (determinant {})",
            c.name,
            r.determinant()
        );
        let q = DQuat::from_mat3(&r).normalize();
        images += &format!(
            "{id} {} {} {} {} {} {} {} {id} {}\n\n",
            q.w, q.x, q.y, q.z, t.x, t.y, t.z, c.name
        );
    }
    write_atomically(&sparse.join("cameras.txt"), &cameras)?;
    write_atomically(&sparse.join("points3D.txt"), "# none\n")?;
    write_atomically(&sparse.join("images.txt"), &images)?;
    println!(
        "{} photos with their cameras ({turned} stood upright, their cameras turned with them): {}",
        calibrations.len(),
        out.display()
    );
    Ok(())
}
