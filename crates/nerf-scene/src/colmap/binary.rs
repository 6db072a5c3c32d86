//! COLMAP's binary model files (`cameras.bin`, `images.bin`, `points3D.bin`), read and
//! written for the parent module. All numbers are little-endian:
//!
//! * `cameras.bin`: `u64` count; per camera `u32` id, `i32` model id, `u64` width, `u64`
//!   height, then the model's parameters as `f64`s (their number set by the model);
//! * `images.bin`: `u64` count; per image `u32` id, `qw qx qy qz tx ty tz` as `f64`s
//!   (world-to-camera), `u32` camera id, the name's bytes ending in a NUL, `u64` feature count,
//!   then per feature `f64` x, `f64` y, `u64` 3D point id (all ones: none);
//! * `points3D.bin`: `u64` count; per point `u64` id, `f64` x y z, `u8` r g b, `f64` error,
//!   `u64` track length, then per track element `u32` image id and `u32` feature index.
//!
//! A count is checked against the bytes left in the file (each record's smallest size)
//! before anything is allocated for it; a file that ends inside a record, or goes on past
//! its last, is an error naming it and the byte where it went wrong.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};

use super::{
    camera_model_by_id, camera_model_by_name, camera_problem, image_problem, point_step,
    write_records, ColmapCameraRecord, ColmapImage, ColmapPoint2D, ColmapPoint3D, MAX_CAMERAS,
    MAX_CAMERAS_FILE_BYTES, MAX_IMAGES, MAX_IMAGES_FILE_BYTES, MAX_IMAGE_NAME_BYTES,
    MAX_POINTS3D_FILE_BYTES,
};
use nerf_files::bounded_read::check_regular_file;

/// The 3D point id COLMAP writes for a feature with no 3D point.
const NO_POINT3D: u64 = u64::MAX;

/// The fewest bytes a camera record takes: ids, size and the fewest parameters (2).
const MIN_CAMERA_BYTES: u64 = 4 + 4 + 8 + 8 + 2 * 8;
/// The fewest bytes an image record takes: id, pose, camera id, a one-byte name and its NUL,
/// feature count.
const MIN_IMAGE_BYTES: u64 = 4 + 7 * 8 + 4 + 2 + 8;
/// The bytes of one 2D feature.
const POINT2D_BYTES: u64 = 8 + 8 + 8;
/// The fewest bytes a 3D point record takes (an empty track).
const MIN_POINT3D_BYTES: u64 = 8 + 3 * 8 + 3 + 8 + 8;
/// The bytes of one track element.
const TRACK_ELEMENT_BYTES: u64 = 4 + 4;

/// A binary file read as a stream, with the bytes left always known.
struct BinaryReader {
    reader: BufReader<File>,
    what: &'static str,
    path: PathBuf,
    len: u64,
    pos: u64,
}

impl BinaryReader {
    /// Opens the regular file `path` of at most `max_bytes`.
    fn open(path: &Path, what: &'static str, max_bytes: u64) -> Result<Self> {
        let len = check_regular_file(path, what, max_bytes)?;
        let file =
            File::open(path).map_err(|e| anyhow!("cannot read {what} {}: {e}", path.display()))?;
        Ok(BinaryReader {
            reader: BufReader::new(file),
            what,
            path: path.to_path_buf(),
            len,
            pos: 0,
        })
    }

    /// An error at byte `at` (where the record it is about starts).
    fn error_at(&mut self, at: u64, message: impl std::fmt::Display) -> anyhow::Error {
        self.pos = at;
        self.error(message)
    }

    /// An error at the current byte.
    fn error(&self, message: impl std::fmt::Display) -> anyhow::Error {
        anyhow!(
            "{} {}: {message} (at byte {} of {})",
            self.what,
            self.path.display(),
            self.pos,
            self.len
        )
    }

    fn left(&self) -> u64 {
        self.len - self.pos
    }

    /// An error unless `n` more bytes are left for `item`.
    fn need(&self, n: u64, item: &str) -> Result<()> {
        if n > self.left() {
            return Err(self.error(format!(
                "truncated: {item} needs {n} bytes, {} are left",
                self.left()
            )));
        }
        Ok(())
    }

    fn bytes<const N: usize>(&mut self, item: &str) -> Result<[u8; N]> {
        self.need(N as u64, item)?;
        let mut b = [0u8; N];
        self.reader
            .read_exact(&mut b)
            .map_err(|e| self.error(format!("cannot read {item}: {e}")))?;
        self.pos += N as u64;
        Ok(b)
    }

    fn u8(&mut self, item: &str) -> Result<u8> {
        Ok(self.bytes::<1>(item)?[0])
    }

    fn u32(&mut self, item: &str) -> Result<u32> {
        self.bytes(item).map(u32::from_le_bytes)
    }

    fn i32(&mut self, item: &str) -> Result<i32> {
        self.bytes(item).map(i32::from_le_bytes)
    }

    fn u64(&mut self, item: &str) -> Result<u64> {
        self.bytes(item).map(u64::from_le_bytes)
    }

    fn f64(&mut self, item: &str) -> Result<f64> {
        self.bytes(item).map(f64::from_le_bytes)
    }

    /// A finite `f64`.
    fn finite(&mut self, item: &str) -> Result<f64> {
        let v = self.f64(item)?;
        if !v.is_finite() {
            self.pos -= 8;
            return Err(self.error(format!("{item} is {v}, not a finite number")));
        }
        Ok(v)
    }

    /// Skips `n` bytes (checked to be there).
    fn skip(&mut self, n: u64, item: &str) -> Result<()> {
        self.need(n, item)?;
        let skipped = std::io::copy(&mut (&mut self.reader).take(n), &mut std::io::sink())
            .map_err(|e| self.error(format!("cannot read {item}: {e}")))?;
        if skipped != n {
            return Err(self.error(format!("{item} was cut short while being read")));
        }
        self.pos += n;
        Ok(())
    }

    /// A count of records of at least `min_bytes` each, checked against the bytes left and
    /// against `max` (`what` names the records, plural).
    fn count(&mut self, what: &str, min_bytes: u64, max: u64) -> Result<u64> {
        let n = self.u64(&format!("the number of {what}"))?;
        let fit = self.left() / min_bytes;
        if n > fit {
            self.pos -= 8;
            return Err(self.error(format!(
                "counts {n} {what}, but the {} bytes after the count hold at most {fit}: the file is truncated or corrupt",
                self.len - self.pos - 8
            )));
        }
        if n > max {
            self.pos -= 8;
            return Err(self.error(format!("counts {n} {what}, more than the {max} read")));
        }
        Ok(n)
    }

    /// An error unless the whole file has been read.
    fn finish(self) -> Result<()> {
        if self.left() > 0 {
            return Err(self.error(format!("{} bytes after the last record", self.left())));
        }
        Ok(())
    }
}

/// Reads `cameras.bin`.
pub(super) fn read_cameras(path: &Path) -> Result<BTreeMap<u32, ColmapCameraRecord>> {
    let mut r = BinaryReader::open(path, "COLMAP cameras file", MAX_CAMERAS_FILE_BYTES)?;
    let n = r.count("cameras", MIN_CAMERA_BYTES, MAX_CAMERAS as u64)?;
    let mut cameras = BTreeMap::new();
    for _ in 0..n {
        let start = r.pos;
        let id = r.u32("a camera id")?;
        let model_id = r.i32("a camera model id")?;
        let Some(info) = camera_model_by_id(model_id) else {
            r.pos -= 4;
            return Err(r.error(format!(
                "camera {id} has model id {model_id}, which COLMAP does not define"
            )));
        };
        let width = r.u64("a camera width")?;
        let height = r.u64("a camera height")?;
        let mut params = Vec::with_capacity(info.num_params);
        for _ in 0..info.num_params {
            params.push(r.finite(&format!("a parameter of camera {id}"))?);
        }
        let camera = ColmapCameraRecord {
            id,
            model: info.name.to_string(),
            width,
            height,
            params,
        };
        if let Some(p) = camera_problem(&camera) {
            return Err(r.error_at(start, p));
        }
        if cameras.insert(id, camera).is_some() {
            return Err(r.error_at(start, format!("a second camera with id {id}")));
        }
    }
    r.finish()?;
    Ok(cameras)
}

/// Reads an image name: bytes up to a NUL, at most [`MAX_IMAGE_NAME_BYTES`] of them.
fn read_name(r: &mut BinaryReader, id: u32) -> Result<String> {
    let start = r.pos;
    let mut bytes = Vec::new();
    loop {
        let b = r.u8(&format!("the name of image {id}"))?;
        if b == 0 {
            break;
        }
        if bytes.len() == MAX_IMAGE_NAME_BYTES {
            let why = format!("the name of image {id} is longer than {MAX_IMAGE_NAME_BYTES} bytes");
            return Err(r.error_at(start, why));
        }
        bytes.push(b);
    }
    String::from_utf8(bytes)
        .map_err(|_| r.error_at(start, format!("the name of image {id} is not UTF-8")))
}

/// Reads `images.bin`, keeping each image's 2D features when `keep_points2d`.
pub(super) fn read_images(path: &Path, keep_points2d: bool) -> Result<Vec<ColmapImage>> {
    let mut r = BinaryReader::open(path, "COLMAP images file", MAX_IMAGES_FILE_BYTES)?;
    let n = r.count("images", MIN_IMAGE_BYTES, MAX_IMAGES as u64)?;
    let mut images = Vec::with_capacity(n.min(1 << 16) as usize);
    for _ in 0..n {
        let start = r.pos;
        let id = r.u32("an image id")?;
        let pose = format!("the pose of image {id}");
        let mut qvec = [0.0; 4];
        for q in &mut qvec {
            *q = r.finite(&pose)?;
        }
        let mut tvec = [0.0; 3];
        for t in &mut tvec {
            *t = r.finite(&pose)?;
        }
        let camera_id = r.u32(&format!("the camera id of image {id}"))?;
        let name = read_name(&mut r, id)?;
        let features = format!("2D features of image {name:?}");
        let count = r.count(&features, POINT2D_BYTES, u64::MAX)?;
        let mut points2d = Vec::new();
        if keep_points2d {
            points2d.reserve_exact(count as usize);
            for _ in 0..count {
                let xy = [r.finite(&features)?, r.finite(&features)?];
                let id = r.u64(&features)?;
                points2d.push(ColmapPoint2D {
                    xy,
                    point3d_id: (id != NO_POINT3D).then_some(id),
                });
            }
        } else {
            r.skip(count * POINT2D_BYTES, &features)?;
        }
        let image = ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        };
        if let Some(p) = image_problem(&image) {
            return Err(r.error_at(start, p));
        }
        images.push(image);
    }
    r.finish()?;
    Ok(images)
}

/// Reads `points3D.bin`, keeping at most `max_points` spread evenly over the file (tracks
/// are skipped).
pub(super) fn read_points3d(path: &Path, max_points: usize) -> Result<Vec<ColmapPoint3D>> {
    let mut r = BinaryReader::open(path, "COLMAP points file", MAX_POINTS3D_FILE_BYTES)?;
    let n = r.count("3D points", MIN_POINT3D_BYTES, u64::MAX)?;
    let step = point_step(n, max_points);
    let mut points = Vec::with_capacity(n.div_ceil(step).min(max_points as u64) as usize);
    for i in 0..n {
        let id = r.u64("a 3D point id")?;
        let what = format!("3D point {id}");
        let keep = i.is_multiple_of(step) && points.len() < max_points;
        if keep {
            let mut xyz = [0.0; 3];
            for v in &mut xyz {
                *v = r.finite(&what)?;
            }
            let rgb = [r.u8(&what)?, r.u8(&what)?, r.u8(&what)?];
            let error = r.finite(&what)?;
            points.push(ColmapPoint3D {
                id,
                xyz,
                rgb,
                error,
            });
        } else {
            r.skip(3 * 8 + 3 + 8, &what)?;
        }
        let track = format!("track elements of {what}");
        let len = r.count(&track, TRACK_ELEMENT_BYTES, u64::MAX)?;
        r.skip(len * TRACK_ELEMENT_BYTES, &track)?;
    }
    r.finish()?;
    Ok(points)
}

/// Writes `cameras.bin` (cameras already checked).
pub(super) fn write_cameras(
    path: &Path,
    cameras: &BTreeMap<u32, ColmapCameraRecord>,
) -> Result<()> {
    write_records(path, cameras.values(), write_count, |w, c| {
        let Some(info) = camera_model_by_name(&c.model) else {
            bail!(
                "camera {} has model {:?}, which COLMAP does not define",
                c.id,
                c.model
            );
        };
        w.write_all(&c.id.to_le_bytes())?;
        w.write_all(&info.id.to_le_bytes())?;
        w.write_all(&c.width.to_le_bytes())?;
        w.write_all(&c.height.to_le_bytes())?;
        write_f64s(w, &c.params)
    })
}

/// Writes `images.bin` (images already checked).
pub(super) fn write_images(path: &Path, images: &[ColmapImage]) -> Result<()> {
    write_records(path, images, write_count, |w, image| {
        w.write_all(&image.id.to_le_bytes())?;
        write_f64s(w, &image.qvec)?;
        write_f64s(w, &image.tvec)?;
        w.write_all(&image.camera_id.to_le_bytes())?;
        w.write_all(image.name.as_bytes())?;
        w.write_all(&[0])?;
        w.write_all(&(image.points2d.len() as u64).to_le_bytes())?;
        for p in &image.points2d {
            write_f64s(w, &p.xy)?;
            w.write_all(&p.point3d_id.unwrap_or(NO_POINT3D).to_le_bytes())?;
        }
        Ok(())
    })
}

/// Writes `points3D.bin` with empty tracks (points already checked).
pub(super) fn write_points3d(path: &Path, points: &[ColmapPoint3D]) -> Result<()> {
    write_records(path, points, write_count, |w, p| {
        w.write_all(&p.id.to_le_bytes())?;
        write_f64s(w, &p.xyz)?;
        w.write_all(&p.rgb)?;
        write_f64s(w, &[p.error])?;
        Ok(w.write_all(&0u64.to_le_bytes())?)
    })
}

/// The record count of a binary model file (`u64`).
fn write_count(w: &mut BufWriter<File>, n: usize) -> Result<()> {
    Ok(w.write_all(&(n as u64).to_le_bytes())?)
}

fn write_f64s(w: &mut BufWriter<File>, values: &[f64]) -> Result<()> {
    for v in values {
        w.write_all(&v.to_le_bytes())?;
    }
    Ok(())
}
