//! The NeRF-synthetic ("Blender") dataset reader: `transforms_{train,val,test}.json` cameras
//! converted to pytorch3d cameras, and RGBA PNGs composited onto a background colour.
//!
//! Layout of a scene directory (e.g. `lego/`):
//!
//! * `transforms_{split}.json`: `camera_angle_x` (horizontal field of view, radians) and
//!   `frames`, each with `file_path` (relative, without the `.png` extension) and
//!   `transform_matrix`, the 4×4 Blender camera-to-world matrix (`[row][col]`).
//! * `{split}/r_{i}.png`: 8-bit RGBA renders, transparent where there is no object.
//!
//! Blender / OpenGL cameras look along their −Z axis with +Y up and +X right; pytorch3d cameras
//! look along +Z with +Y up and +X left (see [`crate::core::camera`]).

use std::fmt;
use std::path::{Component, Path, PathBuf};
use std::str::FromStr;

use anyhow::{anyhow, bail, Result};
use glam::{DMat3, DMat4};
use image::imageops::{self, FilterType};
use image::{ImageBuffer, ImageFormat, Rgba};
use rayon::prelude::*;
use serde::Deserialize;

use crate::core::camera::PerspectiveCamera;
use crate::core::image::RgbImage;
use crate::io::bounded_read::read_regular_file;

/// Where to get the data, appended to errors about a missing scene directory or transforms file.
pub const DOWNLOAD_HINT: &str = "download the NeRF-synthetic lego scene (nerf_synthetic.zip \
    from the original NeRF project's data release) and pass --data-dir or set data.data_dir, \
    or run scripts/download_lego.sh (the default, ../shared/data/lego, is relative to the \
    working directory)";

/// A dataset split, naming `transforms_{split}.json` and the `{split}/` image folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Split {
    /// `train`: the training views.
    Train,
    /// `val`: the validation views.
    Val,
    /// `test`: the test views.
    Test,
}

impl Split {
    /// Every split, in the order of the reference camera file (train, val, test).
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// `"train"`, `"val"` or `"test"`.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }

    /// `transforms_{split}.json` inside `data_dir`.
    pub fn transforms_path(self, data_dir: &Path) -> PathBuf {
        data_dir.join(format!("transforms_{}.json", self.name()))
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Split {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        Split::ALL
            .into_iter()
            .find(|split| split.name() == s)
            .ok_or_else(|| anyhow!("unknown dataset split {s:?} (expected train, val or test)"))
    }
}

/// One view of a split: its image and its camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Path of the RGBA PNG: `data_dir` joined with the JSON's `file_path` (leading `./`
    /// dropped), with `.png` appended when the JSON gives no extension.
    pub file_path: PathBuf,
    /// The view's camera in pytorch3d conventions.
    pub camera: PerspectiveCamera,
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
pub fn blender_to_pytorch3d(
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
pub const MAX_CAMERA_DISTANCE: f64 = 1e4;

/// Largest `transforms_*.json` read (the lego scene's are 60 KB).
pub const MAX_TRANSFORMS_BYTES: u64 = 64 << 20;

/// Largest image file read (an 800×800 RGBA PNG is about 0.5 MB; 16-bit 4096² is 128 MB).
pub const MAX_IMAGE_FILE_BYTES: u64 = 256 << 20;

/// Widest and tallest image file decoded (the NeRF-synthetic renders are 800×800; the f32
/// RGBA copy of an 8192² image is 1 GiB).
pub const MAX_SOURCE_IMAGE_SIDE: u32 = 8192;

/// Checks that the upper 3×3 block of a camera-to-world matrix is a rotation (orthonormal,
/// determinant +1, to 1e-3), the bottom row is `(0, 0, 0, 1)` and the camera centre is within
/// [`MAX_CAMERA_DISTANCE`] of the origin.
pub fn check_rigid(c2w: &[[f64; 4]; 4]) -> Result<()> {
    if c2w.iter().flatten().any(|v| !v.is_finite()) {
        bail!("transform_matrix has a non-finite entry");
    }
    let centre = [c2w[0][3], c2w[1][3], c2w[2][3]];
    let distance = centre.iter().map(|v| v * v).sum::<f64>().sqrt();
    if distance > MAX_CAMERA_DISTANCE {
        bail!(
            "transform_matrix puts the camera {distance:.3e} from the origin, farther than {MAX_CAMERA_DISTANCE:e} scene units"
        );
    }
    let bottom = c2w[3];
    if bottom
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(a, b)| (a - b).abs() > 1e-6)
    {
        bail!("transform_matrix bottom row is {bottom:?}, expected [0, 0, 0, 1]");
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
        bail!("transform_matrix rotation block is not a rotation (|RᵀR − I| = {worst:.2e}, det = {:.4})", m.determinant());
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

/// Reads `data_dir/transforms_{split}.json`: one [`Frame`] per entry of `frames`, in file order.
///
/// Errors (one line, naming the file) when the directory or the file is missing (with
/// [`DOWNLOAD_HINT`]), when the JSON does not parse (with the offending key path), or when a
/// frame's matrix or the field of view is unusable. Images are not opened here.
pub fn read_split(data_dir: &Path, split: Split) -> Result<Vec<Frame>> {
    if data_dir.exists() && !data_dir.is_dir() {
        bail!(
            "dataset directory {} is a file, not a directory; {DOWNLOAD_HINT}",
            data_dir.display()
        );
    }
    if !data_dir.is_dir() {
        bail!(
            "dataset directory {} does not exist; {DOWNLOAD_HINT}",
            data_dir.display()
        );
    }
    let path = split.transforms_path(data_dir);
    if !path.exists() {
        bail!(
            "cannot read {}: it does not exist; {DOWNLOAD_HINT}",
            path.display()
        );
    }
    let bytes = read_regular_file(&path, "dataset file", MAX_TRANSFORMS_BYTES)?;
    parse_split(&bytes, data_dir, &path)
}

/// Parses the text of a `transforms_{split}.json` (read from `path`, named in errors) into
/// frames whose image paths are relative to `data_dir`; see [`read_split`].
pub fn parse_split(bytes: &[u8], data_dir: &Path, path: &Path) -> Result<Vec<Frame>> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let file: TransformsFile = serde_path_to_error::deserialize(&mut de)
        .map_err(|e| anyhow!("cannot parse {}: {e}", path.display()))?;
    let fov = file.camera_angle_x;
    // The NDC focal length 1/tan(fov/2) within the viewer's bounds, 1e-3 to 1e3: a field of
    // view of 1e-300 rad would otherwise score a black view instead of being refused.
    let focal = 1.0 / (fov / 2.0).tan();
    if !(fov.is_finite()
        && fov > 0.0
        && fov < std::f64::consts::PI
        && (1e-3..=1e3).contains(&focal))
    {
        bail!(
            "{}: camera_angle_x = {fov} is not a usable field of view (between 0.002 and 3.139 radians: an NDC focal length from 1e-3 to 1e3)",
            path.display()
        );
    }
    if file.frames.is_empty() {
        bail!("{}: no frames", path.display());
    }
    file.frames
        .iter()
        .enumerate()
        .map(|(i, entry)| {
            let context = |e: anyhow::Error| {
                anyhow!("{}: frame {i} ({}): {e}", path.display(), entry.file_path)
            };
            check_rigid(&entry.transform_matrix).map_err(context)?;
            // The pixel width only enters f_px and cancels in the NDC focal length; the NeRF
            // renders are 800 wide.
            let camera = blender_to_pytorch3d(entry.transform_matrix, fov, 800);
            camera.validate().map_err(context)?;
            Ok(Frame {
                file_path: image_path(data_dir, &entry.file_path),
                camera,
            })
        })
        .collect()
}

/// Reads an RGBA PNG, composites it onto black (or white) and resizes it.
///
/// Returns a `width × height` RGB image, row-major, floats in [0, 1]:
/// `rgb · a + bg · (1 − a)` with `bg` = 0 or 1. Any PNG bit depth or colour type is accepted
/// (no alpha channel means opaque).
///
/// Compositing happens at the file's resolution, then the RGB result is resized with
/// `image`'s `FilterType::Triangle` (bilinear, with the kernel widened by the downscale
/// factor, so downsizing averages like an area filter instead of aliasing). Compositing
/// first is equivalent to resizing premultiplied colour, so no dark or bright fringes appear
/// around the object. When the size already matches nothing is resampled.
///
/// Errors (one line, naming the file) for a zero size, a missing file or an undecodable PNG.
pub fn load_image(
    path: &Path,
    width: usize,
    height: usize,
    white_background: bool,
) -> Result<RgbImage> {
    Ok(load_image_and_transparency(path, width, height, white_background)?.0)
}

/// [`load_image`], and the image's transparency `1 − a` resized the same way (`width × height`
/// values), so that the image on any other background `b` is `image + transparency · (b − bg)`.
pub fn load_image_and_transparency(
    path: &Path,
    width: usize,
    height: usize,
    white_background: bool,
) -> Result<(RgbImage, Vec<f32>)> {
    let loaded = load_frame_image(path, width, height, white_background)?;
    Ok((loaded.image, loaded.transparency))
}

/// One frame's image as [`load_image_and_transparency`] gives it, with what the file itself was.
#[derive(Debug, Clone)]
pub struct LoadedImage {
    /// `width × height` composited RGB.
    pub image: RgbImage,
    /// `width × height` transparencies `1 − a`.
    pub transparency: Vec<f32>,
    /// The file's own `(width, height)`, before resizing.
    pub source_size: (u32, u32),
    /// Whether the file has an alpha channel (without one, every pixel is opaque).
    pub has_alpha: bool,
}

/// [`load_image_and_transparency`] with the file's size and whether it has alpha.
pub fn load_frame_image(
    path: &Path,
    width: usize,
    height: usize,
    white_background: bool,
) -> Result<LoadedImage> {
    let (w, h) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
        _ => bail!(
            "cannot load {} at {width}×{height}: the image size must be positive",
            path.display()
        ),
    };
    let bytes = read_regular_file(path, "image", MAX_IMAGE_FILE_BYTES)?;
    // The decoder's sizes come from the file: bounded before it allocates.
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SOURCE_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_SOURCE_IMAGE_SIDE);
    let mut reader =
        image::ImageReader::with_format(std::io::Cursor::new(&bytes), ImageFormat::Png);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| {
        anyhow!(
            "cannot decode PNG {}: {}",
            path.display(),
            e.to_string().replace('\n', " ")
        )
    })?;
    let has_alpha = decoded.color().has_alpha();
    // (H0, W0, 4) RGBA in [0, 1].
    let rgba = decoded.to_rgba32f();
    let (w0, h0) = rgba.dimensions();
    let bg = if white_background { 1.0 } else { 0.0 };
    // Composited colour and transparency; every channel is resized independently and
    // linearly, so the relation between them survives resizing.
    let composited: Vec<f32> = rgba
        .pixels()
        .flat_map(|p| {
            let a = p[3];
            [
                p[0] * a + bg * (1.0 - a),
                p[1] * a + bg * (1.0 - a),
                p[2] * a + bg * (1.0 - a),
                1.0 - a,
            ]
        })
        .collect();
    // (H0, W0, 4).
    let composited: ImageBuffer<Rgba<f32>, Vec<f32>> = ImageBuffer::from_raw(w0, h0, composited)
        .ok_or_else(|| anyhow!("cannot decode PNG {}: inconsistent size", path.display()))?;
    let resized = if (w0, h0) == (w, h) {
        composited
    } else {
        imageops::resize(&composited, w, h, FilterType::Triangle)
    };
    let raw = resized.into_raw();
    let data = raw
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]].map(|v| v.clamp(0.0, 1.0)))
        .collect();
    let transparency = raw.chunks_exact(4).map(|p| p[3].clamp(0.0, 1.0)).collect();
    Ok(LoadedImage {
        image: RgbImage::new(width, height, data)?,
        transparency,
        source_size: (w0, h0),
        has_alpha,
    })
}

/// A loaded split: frames and their images, all resized to `width × height`.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Cameras and image paths, in the order of `transforms_{split}.json`.
    pub frames: Vec<Frame>,
    /// `frames.len()` images, each `width × height × 3` floats in [0, 1].
    pub images: Vec<RgbImage>,
    /// Per image, `width × height` transparencies `1 − a` (see
    /// [`load_image_and_transparency`]); empty when unknown.
    pub transparency: Vec<Vec<f32>>,
    /// Width of every image, in pixels.
    pub width: usize,
    /// Height of every image, in pixels.
    pub height: usize,
}

impl Dataset {
    /// Reads a split's cameras ([`read_split`]) and loads every image ([`load_image`]) in
    /// parallel. The first failure is returned, naming its file.
    pub fn load(
        data_dir: &Path,
        split: Split,
        width: usize,
        height: usize,
        white_background: bool,
    ) -> Result<Self> {
        Self::load_first(data_dir, split, width, height, white_background, None)
    }

    /// [`Dataset::load`] of the first `limit` frames only (all with `None`): the other images
    /// are not opened. Every image must have the size of the split's first; an image without
    /// an alpha channel is taken as opaque (a note on stderr says how many).
    pub fn load_first(
        data_dir: &Path,
        split: Split,
        width: usize,
        height: usize,
        white_background: bool,
        limit: Option<usize>,
    ) -> Result<Self> {
        let mut frames = read_split(data_dir, split)?;
        frames.truncate(limit.unwrap_or(frames.len()));
        let loaded = frames
            .par_iter()
            .map(|frame| load_frame_image(&frame.file_path, width, height, white_background))
            .collect::<Result<Vec<_>>>()?;
        check_sizes_agree(&frames, &loaded)?;
        let opaque = loaded.iter().filter(|l| !l.has_alpha).count();
        if opaque > 0 {
            crate::core::term::note(&format!(
                "note: {opaque} of the {} images of {} have no alpha channel and are taken as \
                 opaque (no background compositing applies to them)",
                loaded.len(),
                split.transforms_path(data_dir).display()
            ));
        }
        let (images, transparency) = loaded
            .into_iter()
            .map(|l| (l.image, l.transparency))
            .unzip();
        Ok(Self {
            frames,
            images,
            transparency,
            width,
            height,
        })
    }
}

/// An error naming the first image whose file size differs from the first frame's: a split's
/// images share one camera model, so a frame of another size cannot be scored against it.
fn check_sizes_agree(frames: &[Frame], loaded: &[LoadedImage]) -> Result<()> {
    let Some(first) = loaded.first() else {
        return Ok(());
    };
    for (frame, image) in frames.iter().zip(loaded) {
        if image.source_size != first.source_size {
            bail!(
                "{} is {}x{}, but the split's images are {}x{} ({}): every image of a split must \
                 have the same size",
                frame.file_path.display(),
                image.source_size.0,
                image.source_size.1,
                first.source_size.0,
                first.source_size.1,
                frames[0].file_path.display()
            );
        }
    }
    Ok(())
}

/// The default scene directory `../shared/data/<dataset_name>`, relative to the working
/// directory (used when the config has no `data.data_dir`).
pub fn default_data_dir(dataset_name: &str) -> PathBuf {
    Path::new("..")
        .join("shared")
        .join("data")
        .join(dataset_name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::camera::look_at_rotation;
    use crate::core::rays::ray_through_ndc;
    use glam::DVec3;
    use std::time::Instant;

    /// The shared lego scene, or `None` (with a message) when it is not on this machine.
    fn lego_dir() -> Option<PathBuf> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(default_data_dir("lego"));
        if dir.join("transforms_train.json").is_file() {
            Some(dir)
        } else {
            eprintln!(
                "skipping: lego scene not found at {} ({DOWNLOAD_HINT})",
                dir.display()
            );
            None
        }
    }

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
        let Some(dir) = lego_dir() else { return };
        let reference_path = dir.join("cameras_pytorch3d.json");
        let Ok(text) = std::fs::read_to_string(&reference_path) else {
            eprintln!("skipping: {} not found", reference_path.display());
            return;
        };
        let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
        let frames: Vec<Frame> = Split::ALL
            .into_iter()
            .flat_map(|split| read_split(&dir, split).unwrap())
            .collect();
        assert_eq!(frames.len(), 400);
        let number = |v: &serde_json::Value| v.as_f64().unwrap();
        let (mut dr, mut dt, mut df) = (0.0f64, 0.0f64, 0.0f64);
        for (k, frame) in frames.iter().enumerate() {
            let cam = &frame.camera;
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
        let Some(dir) = lego_dir() else { return };
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
    fn real_frame_loads_small() {
        let Some(dir) = lego_dir() else { return };
        let frames = read_split(&dir, Split::Train).unwrap();
        let path = &frames[0].file_path;
        let black = load_image(path, 32, 32, false).unwrap();
        assert_eq!(
            (black.width, black.height, black.data.len()),
            (32, 32, 32 * 32 * 3)
        );
        assert!(black.data.iter().all(|v| (0.0..=1.0).contains(v)));
        assert_eq!(&black.data[..3], &[0.0, 0.0, 0.0]);
        // The object is there: some pixels are lit.
        assert!(black.data.iter().any(|&v| v > 0.2));
        let white = load_image(path, 32, 32, true).unwrap();
        // Resampling weights sum to 1 only up to f32 rounding.
        assert!(
            white.data[..3].iter().all(|&v| v > 1.0 - 1e-5),
            "{:?}",
            &white.data[..3]
        );
    }

    #[test]
    fn whole_train_split_loads() {
        let Some(dir) = lego_dir() else { return };
        let start = Instant::now();
        let data = Dataset::load(&dir, Split::Train, 128, 128, false).unwrap();
        eprintln!(
            "loaded {} train images at 128×128 in {:.2?}",
            data.images.len(),
            start.elapsed()
        );
        assert_eq!(data.frames.len(), 100);
        assert_eq!(data.images.len(), 100);
        assert!(data
            .images
            .iter()
            .all(|im| im.width == 128 && im.height == 128 && im.data.len() == 128 * 128 * 3));
    }

    #[test]
    fn compositing_follows_alpha() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        // Two pixels: half-transparent red, fully transparent green.
        let rgba: ImageBuffer<image::Rgba<u8>, Vec<u8>> =
            ImageBuffer::from_raw(2, 1, vec![255, 0, 0, 102, 0, 255, 0, 0]).unwrap();
        rgba.save(&path).unwrap();
        let a = 102.0 / 255.0;
        let black = load_image(&path, 2, 1, false).unwrap();
        let expected = [a, 0.0, 0.0, 0.0, 0.0, 0.0];
        for (v, e) in black.data.iter().zip(expected) {
            assert!((v - e).abs() < 1e-6, "{:?}", black.data);
        }
        let white = load_image(&path, 2, 1, true).unwrap();
        let expected = [1.0, 1.0 - a, 1.0 - a, 1.0, 1.0, 1.0];
        for (v, e) in white.data.iter().zip(expected) {
            assert!((v - e).abs() < 1e-6, "{:?}", white.data);
        }
        // Downsizing to one pixel averages the composited colours.
        let one = load_image(&path, 1, 1, false).unwrap();
        assert!((one.data[0] - a / 2.0).abs() < 1e-6, "{:?}", one.data);
        // The transparency carries an image from one background to another, resized or not.
        for (w, h) in [(2, 1), (1, 1)] {
            let (black, t) = load_image_and_transparency(&path, w, h, false).unwrap();
            let white = load_image(&path, w, h, true).unwrap();
            assert_eq!(t.len(), w * h);
            for (i, (b, wh)) in black.data.iter().zip(&white.data).enumerate() {
                assert!((b + t[i / 3] - wh).abs() < 1e-6, "{:?} {t:?}", black.data);
            }
        }
        let (_, t) = load_image_and_transparency(&path, 2, 1, false).unwrap();
        assert!((t[0] - (1.0 - a)).abs() < 1e-6 && (t[1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn missing_directory_says_where_to_get_the_data() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("lego");
        let err = read_split(&missing, Split::Train).unwrap_err().to_string();
        eprintln!("{err}");
        assert!(err.contains(&missing.display().to_string()), "{err}");
        assert!(err.contains("nerf_synthetic.zip") && err.contains("scripts/download_lego.sh"));
        assert!(!err.contains('\n'), "{err}");
        let err = Dataset::load(&missing, Split::Val, 8, 8, false)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(err.contains("data.data_dir"), "{err}");
        // An existing directory without the transforms file names the file.
        let err = read_split(dir.path(), Split::Test).unwrap_err().to_string();
        eprintln!("{err}");
        assert!(
            err.contains("transforms_test.json") && err.contains("download_lego.sh"),
            "{err}"
        );
    }

    #[test]
    fn bad_json_names_the_file_and_key() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("transforms_train.json");
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
        assert_eq!(frames[0].camera.t, [0.0, 0.0, 4.0]);
        assert!((frames[0].camera.focal[0] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn corrupt_or_missing_png_names_the_file() {
        let mut file = tempfile::Builder::new().suffix(".png").tempfile().unwrap();
        std::io::Write::write_all(&mut file, b"\x89PNG\r\n\x1a\n this is not a png").unwrap();
        let err = load_image(file.path(), 8, 8, false)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(err.contains(&file.path().display().to_string()), "{err}");
        assert!(!err.contains('\n'), "{err}");
        let missing = file.path().with_file_name("no_such_image.png");
        let err = load_image(&missing, 8, 8, false).unwrap_err().to_string();
        eprintln!("{err}");
        assert!(err.contains("no_such_image.png"), "{err}");
        let err = load_image(file.path(), 0, 8, false)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(err.contains("size"), "{err}");
    }
}
