//! COLMAP sparse models: cameras (intrinsics), images (poses and names) and 3D points, read
//! from and written to COLMAP's text (`cameras.txt`, `images.txt`, `points3D.txt`) and binary
//! (`cameras.bin`, `images.bin`, `points3D.bin`) formats (the private `text` and `binary`
//! submodules, which document the layouts), and found in a capture directory
//! ([`find_model`]).
//!
//! Values are stored as COLMAP stores them: camera parameters by model name, unconverted;
//! image poses world-to-camera (`qvec` = `[qw, qx, qy, qz]`, `tvec`). Turning them into rays
//! is the camera models' business, not this module's.
//!
//! Every input is a regular file of bounded size ([`check_regular_file`]), read as a stream;
//! every count read from a binary file is checked against the bytes left before anything is
//! allocated for it, and every text line is bounded (`MAX_TEXT_LINE_BYTES`). A points file
//! can be huge: at most [`ColmapReadOptions::max_points3d`] points are kept, evenly spread
//! over the file. Files newer COLMAP writes beside the model (`rigs.bin`, `frames.bin`) are
//! ignored: `images.*` holds each image's composed world-to-camera pose either way. Errors
//! are one line naming the file, and the line for text files.
//!
//! [`check_regular_file`]: nerf_files::bounded_read::check_regular_file

use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Component, Path, PathBuf};

use anyhow::{anyhow, bail, Result};

mod binary;
mod text;

/// A COLMAP camera model: its id in binary files, its name in text files and how many
/// parameters it takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct CameraModelInfo {
    /// The model's id in `cameras.bin`.
    pub id: i32,
    /// The model's name in `cameras.txt` (and in [`ColmapCameraRecord::model`]).
    pub name: &'static str,
    /// How many parameters a camera of this model has.
    pub num_params: usize,
}

const fn model(id: i32, name: &'static str, num_params: usize) -> CameraModelInfo {
    CameraModelInfo {
        id,
        name,
        num_params,
    }
}

/// Every camera model COLMAP defines (`src/colmap/sensor/models.h`), in id order; ids are
/// only ever appended there, so older files read the same.
pub(crate) const CAMERA_MODELS: [CameraModelInfo; 18] = [
    model(0, "SIMPLE_PINHOLE", 3),
    model(1, "PINHOLE", 4),
    model(2, "SIMPLE_RADIAL", 4),
    model(3, "RADIAL", 5),
    model(4, "OPENCV", 8),
    model(5, "OPENCV_FISHEYE", 8),
    model(6, "FULL_OPENCV", 12),
    model(7, "FOV", 5),
    model(8, "SIMPLE_RADIAL_FISHEYE", 4),
    model(9, "RADIAL_FISHEYE", 5),
    model(10, "THIN_PRISM_FISHEYE", 12),
    model(11, "RAD_TAN_THIN_PRISM_FISHEYE", 16),
    model(12, "SIMPLE_DIVISION", 4),
    model(13, "DIVISION", 5),
    model(14, "SIMPLE_FISHEYE", 3),
    model(15, "FISHEYE", 4),
    model(16, "EUCM", 6),
    model(17, "EQUIRECTANGULAR", 2),
];

/// The camera model named `name` (as in `cameras.txt`), if COLMAP defines one.
pub(crate) fn camera_model_by_name(name: &str) -> Option<&'static CameraModelInfo> {
    CAMERA_MODELS.iter().find(|m| m.name == name)
}

/// The camera model with id `id` (as in `cameras.bin`), if COLMAP defines one.
pub(crate) fn camera_model_by_id(id: i32) -> Option<&'static CameraModelInfo> {
    CAMERA_MODELS.iter().find(|m| m.id == id)
}

/// One camera as COLMAP's `cameras.txt` or `cameras.bin` records it (a set of intrinsics several
/// images may share); the camera model it describes is
/// [`nerf_core::camera::ColmapCamera`].
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCameraRecord {
    /// The camera's id, which images refer to.
    pub id: u32,
    /// COLMAP's model name, e.g. `"OPENCV"` (one of `CAMERA_MODELS`).
    pub model: String,
    /// Image width in pixels.
    pub width: u64,
    /// Image height in pixels.
    pub height: u64,
    /// The model's parameters in COLMAP's order (focal lengths, principal point, then
    /// distortion), as many as `CameraModelInfo::num_params`.
    pub params: Vec<f64>,
}

/// One 2D feature of an image and the 3D point it observes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColmapPoint2D {
    /// Pixel position `[x, y]` (COLMAP's convention: the top-left corner of the image is
    /// `(0, 0)`, the first pixel's centre `(0.5, 0.5)`).
    pub xy: [f64; 2],
    /// The id of the 3D point observed, `None` when the feature is not triangulated (`-1`
    /// in text files).
    pub point3d_id: Option<u64>,
}

/// One registered image: its pose and camera.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    /// The image's id.
    pub id: u32,
    /// World-to-camera rotation as a quaternion `[qw, qx, qy, qz]`, as COLMAP stores it (not
    /// necessarily of unit norm; never zero).
    pub qvec: [f64; 4],
    /// World-to-camera translation, as COLMAP stores it: the camera centre is `-R^T t`.
    pub tvec: [f64; 3],
    /// The id of the image's camera, a key of [`ColmapModel::cameras`].
    pub camera_id: u32,
    /// The image file's path relative to the image folder, subfolders allowed (`/`-separated,
    /// never absolute, no `..`).
    pub name: String,
    /// The image's 2D features; read only when [`ColmapReadOptions::points2d`] asks for
    /// them, empty otherwise.
    pub points2d: Vec<ColmapPoint2D>,
}

/// One triangulated 3D point (its track, the images observing it, is not kept).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColmapPoint3D {
    /// The point's id.
    pub id: u64,
    /// Position in world coordinates.
    pub xyz: [f64; 3],
    /// Colour, 0 to 255.
    pub rgb: [u8; 3],
    /// Mean reprojection error in pixels.
    pub error: f64,
}

/// A COLMAP sparse model.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ColmapModel {
    /// The cameras by id.
    pub cameras: BTreeMap<u32, ColmapCameraRecord>,
    /// The registered images, sorted by name; each one's camera is in `cameras`.
    pub images: Vec<ColmapImage>,
    /// The 3D points kept (see [`ColmapReadOptions::max_points3d`]), in file order.
    pub points: Vec<ColmapPoint3D>,
}

impl ColmapModel {
    /// The camera of `image` (one of this model's images).
    ///
    /// # Panics
    /// When the image's camera is not in the model (never for a model read by this module).
    pub fn camera_of(&self, image: &ColmapImage) -> &ColmapCameraRecord {
        &self.cameras[&image.camera_id]
    }
}

/// Which of COLMAP's two formats a model is stored in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColmapFormat {
    /// `cameras.txt`, `images.txt`, `points3D.txt`.
    Text,
    /// `cameras.bin`, `images.bin`, `points3D.bin` (little-endian).
    Binary,
}

impl ColmapFormat {
    /// The extension of this format's files, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            ColmapFormat::Text => "txt",
            ColmapFormat::Binary => "bin",
        }
    }

    /// The paths of the cameras, images and 3D points files of a model in this format in
    /// `dir`.
    pub fn files(self, dir: &Path) -> [PathBuf; 3] {
        let ext = self.extension();
        ["cameras", "images", "points3D"].map(|stem| dir.join(format!("{stem}.{ext}")))
    }
}

/// The largest cameras file read (256 MiB: over a million cameras).
pub(crate) const MAX_CAMERAS_FILE_BYTES: u64 = 256 << 20;
/// The largest images file read (16 GiB: 2D features make it large).
pub(crate) const MAX_IMAGES_FILE_BYTES: u64 = 16 << 30;
/// The largest points file read (64 GiB; it is streamed, and at most
/// [`ColmapReadOptions::max_points3d`] points are kept).
pub(crate) const MAX_POINTS3D_FILE_BYTES: u64 = 64 << 30;
/// The most cameras a model may have.
pub(crate) const MAX_CAMERAS: usize = 1 << 20;
/// The most images a model may have.
pub(crate) const MAX_IMAGES: usize = 1 << 20;
/// The longest image name, in bytes.
pub(crate) const MAX_IMAGE_NAME_BYTES: usize = 4096;
/// The longest line of a text file, in bytes (an image's 2D features are one line).
pub(crate) const MAX_TEXT_LINE_BYTES: usize = 64 << 20;
/// How many 3D points are kept by default: 1 000 000 (about 48 MB).
pub(crate) const DEFAULT_MAX_POINTS3D: usize = 1_000_000;

/// What to read of a model beyond cameras and image poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ColmapReadOptions {
    /// Keep each image's 2D features ([`ColmapImage::points2d`]); off by default, as a
    /// dataset needs only the poses.
    pub points2d: bool,
    /// Keep at most this many 3D points, every k-th of the file's so that they cover the
    /// whole scene; 0 skips the points file altogether. `DEFAULT_MAX_POINTS3D` by default.
    pub max_points3d: usize,
}

impl Default for ColmapReadOptions {
    fn default() -> Self {
        ColmapReadOptions {
            points2d: false,
            max_points3d: DEFAULT_MAX_POINTS3D,
        }
    }
}

/// The step between the points kept when a file of `total` points is read under a limit of
/// `max`: every `step`-th point from the first, at most `max` of them.
fn point_step(total: u64, max: usize) -> u64 {
    total.div_ceil(max.max(1) as u64).max(1)
}

/// Why `name` cannot be an image name (empty, too long, absolute, with a `..` component, a
/// NUL or line break, or space at either end), if it cannot.
fn image_name_problem(name: &str) -> Option<String> {
    if name.is_empty() {
        return Some("an empty image name".into());
    }
    if name.len() > MAX_IMAGE_NAME_BYTES {
        return Some(format!(
            "an image name of {} bytes, more than {MAX_IMAGE_NAME_BYTES}",
            name.len()
        ));
    }
    if name.contains(['\0', '\n', '\r']) || name.trim() != name {
        return Some(format!(
            "image name {name:?}, with a NUL, a line break or space at an end"
        ));
    }
    let path = Path::new(name);
    if path.is_absolute() || path.components().any(|c| c == Component::ParentDir) {
        return Some(format!(
            "image name {name:?}, not a path inside the image folder"
        ));
    }
    None
}

/// An error unless every value of `values` is finite; `what` names them for the message.
fn check_finite(values: &[f64], what: &str) -> Result<(), String> {
    match values.iter().find(|v| !v.is_finite()) {
        Some(v) => Err(format!("{what} holds {v}, not a finite number")),
        None => Ok(()),
    }
}

/// Checks a camera's model, parameter count, parameters and size.
fn camera_problem(camera: &ColmapCameraRecord) -> Option<String> {
    let id = camera.id;
    let Some(info) = camera_model_by_name(&camera.model) else {
        return Some(format!(
            "camera {id} has model {:?}, which COLMAP does not define",
            camera.model
        ));
    };
    if camera.params.len() != info.num_params {
        return Some(format!(
            "camera {id} ({}) has {} parameters, not {}",
            info.name,
            camera.params.len(),
            info.num_params
        ));
    }
    if camera.width == 0 || camera.height == 0 {
        return Some(format!(
            "camera {id} is {}x{} pixels",
            camera.width, camera.height
        ));
    }
    check_finite(&camera.params, &format!("camera {id}'s parameters")).err()
}

/// Checks an image's name, pose values and quaternion.
fn image_problem(image: &ColmapImage) -> Option<String> {
    if let Some(p) = image_name_problem(&image.name) {
        return Some(format!("image {} has {p}", image.id));
    }
    let what = format!("image {:?}'s pose", image.name);
    if let Err(p) = check_finite(&image.qvec, &what).and(check_finite(&image.tvec, &what)) {
        return Some(p);
    }
    if image.qvec.iter().all(|&q| q == 0.0) {
        return Some(format!("image {:?} has a zero quaternion", image.name));
    }
    image
        .points2d
        .iter()
        .find_map(|p| check_finite(&p.xy, &format!("image {:?}'s 2D features", image.name)).err())
}

/// Checks a model as a whole: cameras, at least one image, every image's camera defined, ids
/// and names unique, every value finite. `files` are the cameras, images and points files the
/// errors name.
fn check_model(model: &ColmapModel, files: &[PathBuf; 3]) -> Result<()> {
    let [cameras, images, points] = files.each_ref().map(|p| p.display());
    for (&id, camera) in &model.cameras {
        if id != camera.id {
            bail!("{cameras}: camera {} is filed under id {id}", camera.id);
        }
        if let Some(p) = camera_problem(camera) {
            bail!("{cameras}: {p}");
        }
    }
    if model.images.is_empty() {
        bail!("{images} holds no images: the model has no registered image");
    }
    if model.images.len() > MAX_IMAGES {
        bail!("{images} holds more than {MAX_IMAGES} images");
    }
    let mut ids = HashSet::new();
    let mut names = HashSet::new();
    for image in &model.images {
        if let Some(p) = image_problem(image) {
            bail!("{images}: {p}");
        }
        if !model.cameras.contains_key(&image.camera_id) {
            bail!(
                "{images}: image {:?} (id {}) uses camera {}, which {cameras} does not define",
                image.name,
                image.id,
                image.camera_id
            );
        }
        if !ids.insert(image.id) {
            bail!("{images}: two images have id {}", image.id);
        }
        if !names.insert(image.name.as_str()) {
            bail!("{images}: two images are named {:?}", image.name);
        }
    }
    for point in &model.points {
        let what = format!("3D point {}", point.id);
        if let Err(p) = check_finite(&point.xyz, &what).and(check_finite(&[point.error], &what)) {
            bail!("{points}: {p}");
        }
    }
    Ok(())
}

/// The format of the model stored in `dir` itself, if any: binary when `cameras.bin` and
/// `images.bin` are there, else text when `cameras.txt` and `images.txt` are (binary is
/// preferred when both are, with a note). The points file is optional.
pub fn model_format(dir: &Path) -> Option<ColmapFormat> {
    let has = |f: ColmapFormat| {
        let [cameras, images, _] = f.files(dir);
        cameras.exists() && images.exists()
    };
    match (has(ColmapFormat::Binary), has(ColmapFormat::Text)) {
        (true, text) => {
            if text {
                log::info!(
                    "{} holds a COLMAP model in both binary and text files; reading the binary ones",
                    dir.display()
                );
            }
            Some(ColmapFormat::Binary)
        }
        (false, true) => Some(ColmapFormat::Text),
        (false, false) => None,
    }
}

/// Reads the model stored in `dir` itself (see [`model_format`]), then checks it: at least
/// one image, each image's camera defined, ids and names unique, every value finite. Images
/// come sorted by name. Without a points file the model has no points.
pub fn read_model(dir: &Path, options: &ColmapReadOptions) -> Result<ColmapModel> {
    let Some(format) = model_format(dir) else {
        bail!(
            "no COLMAP model in {}: it holds neither cameras.bin and images.bin nor cameras.txt and images.txt",
            dir.display()
        );
    };
    let files = format.files(dir);
    let [cameras_file, images_file, points_file] = &files;
    let (cameras, mut images) = match format {
        ColmapFormat::Binary => (
            binary::read_cameras(cameras_file)?,
            binary::read_images(images_file, options.points2d)?,
        ),
        ColmapFormat::Text => (
            text::read_cameras(cameras_file)?,
            text::read_images(images_file, options.points2d)?,
        ),
    };
    let points = if options.max_points3d == 0 {
        Vec::new()
    } else if !points_file.exists() {
        log::info!(
            "{} has no {}: the model has no 3D points",
            dir.display(),
            points_file
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
        );
        Vec::new()
    } else {
        match format {
            ColmapFormat::Binary => binary::read_points3d(points_file, options.max_points3d)?,
            ColmapFormat::Text => text::read_points3d(points_file, options.max_points3d)?,
        }
    };
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let model = ColmapModel {
        cameras,
        images,
        points,
    };
    check_model(&model, &files)?;
    Ok(model)
}

/// The subfolders of `dir` that hold a model, numbered ones (COLMAP's `sparse/0`, `sparse/1`,
/// ...) in number order, then others by name; none when `dir` is not a readable folder.
fn model_subdirs(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut subdirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir() && model_format(p).is_some())
        .collect();
    let key = |p: &PathBuf| {
        let name = p
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        (name.parse::<u64>().unwrap_or(u64::MAX), name)
    };
    subdirs.sort_by_key(key);
    subdirs
}

/// Of several model folders, the one with the most registered images (the first of those
/// tied); a folder whose model cannot be read is skipped with a warning, unless none can.
fn choose_model(candidates: &[PathBuf]) -> Result<PathBuf> {
    let poses_only = ColmapReadOptions {
        points2d: false,
        max_points3d: 0,
    };
    let mut best: Option<(usize, &PathBuf)> = None;
    let mut first_error = None;
    let mut counts = Vec::new();
    for dir in candidates {
        match read_model(dir, &poses_only) {
            Ok(m) => {
                counts.push(format!("{}: {}", dir.display(), m.images.len()));
                if best.is_none_or(|(n, _)| m.images.len() > n) {
                    best = Some((m.images.len(), dir));
                }
            }
            Err(e) => {
                log::warn!("skipping the COLMAP model in {}: {e}", dir.display());
                first_error.get_or_insert(e);
            }
        }
    }
    match (best, first_error) {
        (Some((n, dir)), _) => {
            log::info!(
                "{} COLMAP models; using {}, which has the most registered images ({n}; {})",
                candidates.len(),
                dir.display(),
                counts.join(", ")
            );
            Ok(dir.clone())
        }
        (None, Some(e)) => Err(e),
        (None, None) => bail!("no COLMAP model to choose from"),
    }
}

/// [`find_model_with`] under the default options (poses, no 2D features, at most
/// `DEFAULT_MAX_POINTS3D` points).
pub fn find_model(dir: &Path) -> Result<(PathBuf, ColmapModel)> {
    find_model_with(dir, &ColmapReadOptions::default())
}

/// Finds and reads the COLMAP model of a capture directory; returns the model's folder and
/// the model. Looked for, in this order: the model files in `dir` itself (`dir` is the model
/// folder), in `dir/sparse`, in `dir/colmap/sparse` (nerfstudio's layout); at each place, when
/// the files are not there, its subfolders holding a model (`sparse/0`, `sparse/1`, ...): of
/// several, the one with the most registered images, named with `log::info!`. Text or binary
/// (see [`model_format`]); other files (`rigs.bin`, `frames.bin`, `project.ini`) are ignored.
/// Errors (one line): `dir` not a folder, no model found (naming the places looked), or the
/// model's own errors ([`read_model`]).
pub fn find_model_with(dir: &Path, options: &ColmapReadOptions) -> Result<(PathBuf, ColmapModel)> {
    if !dir.is_dir() {
        bail!(
            "cannot look for a COLMAP model in {}: not a folder",
            dir.display()
        );
    }
    for place in &model_places(dir) {
        if model_format(place).is_some() {
            return Ok((place.clone(), read_model(place, options)?));
        }
        let subdirs = model_subdirs(place);
        let chosen = match subdirs.len() {
            0 => continue,
            1 => subdirs[0].clone(),
            _ => choose_model(&subdirs)?,
        };
        let model = read_model(&chosen, options)?;
        return Ok((chosen, model));
    }
    let d = dir.display();
    bail!(
        "no COLMAP model found in {d}: looked for cameras.bin and images.bin (or cameras.txt and images.txt) in {d}, {d}/sparse and {d}/colmap/sparse, and in their subfolders (sparse/0, ...)"
    )
}

/// Where [`find_model_with`] looks for a model, in order.
fn model_places(dir: &Path) -> [PathBuf; 3] {
    [
        dir.to_path_buf(),
        dir.join("sparse"),
        dir.join("colmap").join("sparse"),
    ]
}

/// Whether `dir` holds a COLMAP model where [`find_model_with`] looks: the first such place
/// (the model folder, or the folder of several models), without reading any model.
pub fn find_model_folder(dir: &Path) -> Option<PathBuf> {
    model_places(dir)
        .into_iter()
        .find(|place| model_format(place).is_some() || !model_subdirs(place).is_empty())
}

/// Writes a model file at `path` (atomically): `head` with the number of records, then each
/// record by `write_record`. The text and binary writers share it.
fn write_records<'a, T: 'a>(
    path: &Path,
    records: impl IntoIterator<Item = &'a T, IntoIter: ExactSizeIterator>,
    head: impl FnOnce(&mut BufWriter<File>, usize) -> Result<()>,
    write_record: impl Fn(&mut BufWriter<File>, &T) -> Result<()>,
) -> Result<()> {
    let mut records = records.into_iter();
    nerf_files::output::write_atomically(path, |w| {
        head(w, records.len())?;
        records.try_for_each(|record| write_record(w, record))
    })
}

/// Checks `model` before writing it to `dir` in `format` (never write what could not be
/// read back), creates `dir`, and returns the files to write.
fn prepare_write(dir: &Path, model: &ColmapModel, format: ColmapFormat) -> Result<[PathBuf; 3]> {
    let files = format.files(dir);
    check_model(model, &files)?;
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("cannot create {}: {e}", dir.display()))?;
    Ok(files)
}

/// Writes `model` to `dir` (created if missing) as `cameras.bin`, `images.bin` and
/// `points3D.bin`, each file atomically. 3D points are written with empty tracks. Errors
/// (one line) for a model [`read_model`] would refuse.
pub fn write_binary(dir: &Path, model: &ColmapModel) -> Result<()> {
    let [cameras, images, points] = prepare_write(dir, model, ColmapFormat::Binary)?;
    binary::write_cameras(&cameras, &model.cameras)?;
    binary::write_images(&images, &model.images)?;
    binary::write_points3d(&points, &model.points)
}

/// Writes `model` to `dir` (created if missing) as `cameras.txt`, `images.txt` and
/// `points3D.txt`, each file atomically, numbers in the shortest form that reads back to the
/// same value. 3D points are written with empty tracks. Errors (one line) for a model
/// [`read_model`] would refuse.
pub fn write_text(dir: &Path, model: &ColmapModel) -> Result<()> {
    let [cameras, images, points] = prepare_write(dir, model, ColmapFormat::Text)?;
    text::write_cameras(&cameras, &model.cameras)?;
    text::write_images(&images, &model.images)?;
    text::write_points3d(&points, &model.points)
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_model_table_matches_colmap_ids_and_names() {
        for (i, m) in CAMERA_MODELS.iter().enumerate() {
            assert_eq!(m.id, i as i32);
            assert_eq!(camera_model_by_name(m.name), Some(m));
            assert_eq!(camera_model_by_id(m.id), Some(m));
        }
        assert_eq!(camera_model_by_name("FULL_OPENCV").unwrap().num_params, 12);
        assert_eq!(camera_model_by_name("OPENCV_FISHEYE").unwrap().id, 5);
        assert_eq!(camera_model_by_id(10).unwrap().name, "THIN_PRISM_FISHEYE");
        assert!(camera_model_by_id(18).is_none() && camera_model_by_id(-1).is_none());
    }

    #[test]
    fn image_names_are_relative_paths_inside_the_image_folder() {
        assert!(image_name_problem("a/b/c.png").is_none());
        assert!(image_name_problem("frame 001.jpg").is_none());
        for bad in [
            "",
            "/etc/passwd",
            "../x.png",
            "a/../../x.png",
            " x.png",
            "a\nb",
        ] {
            assert!(image_name_problem(bad).is_some(), "{bad:?}");
        }
    }

    #[test]
    fn point_step_keeps_at_most_the_limit_spread_over_the_file() {
        assert_eq!(point_step(10, 100), 1);
        assert_eq!(point_step(100, 10), 10);
        assert_eq!(point_step(101, 10), 11);
        // Every step-th of `total` from the first: ceil(total / step) <= max.
        for (total, max) in [(101u64, 10usize), (1_000_003, 1000), (7, 3)] {
            let kept = total.div_ceil(point_step(total, max));
            assert!(kept <= max as u64 && kept * 2 > max as u64, "{total} {max}");
        }
    }
}
