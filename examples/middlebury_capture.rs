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
//! Run: `cargo run --release --example middlebury_capture -- SET_DIR OUT`, e.g.
//! `SET_DIR = ../shared/data/real/temple_ring` (it holds `templeR_par.txt` and `images/`, or
//! the photos beside the file as the original download has them).

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use glam::{DMat3, DQuat};

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
        let id = i + 1;
        cameras += &format!(
            "{id} PINHOLE {w} {h} {} {} {} {}\n",
            c.k[0], c.k[4], c.k[2], c.k[5]
        );
        let r = DMat3::from_cols_array(&c.r).transpose();
        ensure!(
            (r.determinant() - 1.0).abs() < 1e-3,
            "{}: R is not a rotation (determinant {})",
            c.name,
            r.determinant()
        );
        let q = DQuat::from_mat3(&r).normalize();
        images += &format!(
            "{id} {} {} {} {} {} {} {} {id} {}\n\n",
            q.w, q.x, q.y, q.z, c.t[0], c.t[1], c.t[2], c.name
        );
    }
    write_atomically(&sparse.join("cameras.txt"), &cameras)?;
    write_atomically(&sparse.join("points3D.txt"), "# none\n")?;
    write_atomically(&sparse.join("images.txt"), &images)?;
    println!(
        "{} photos with their cameras: {}",
        calibrations.len(),
        out.display()
    );
    Ok(())
}
