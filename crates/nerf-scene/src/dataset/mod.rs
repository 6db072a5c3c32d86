//! Scene data: the NeRF-synthetic release and the captures of other NeRF tools, read into
//! frames (a photo, its camera, its mask) of one normalised scene.
//!
//! * The formats, one file each, listed once in `SCENE_FORMATS` and told apart by what the
//!   folder holds ([`SceneFormat::detect`]): NeRF-synthetic `transforms_{split}.json`
//!   ([`transforms`]), nerfstudio or instant-ngp `transforms.json` ([`nerfstudio`]), LLFF
//!   `poses_bounds.npy` ([`llff`]) and COLMAP models ([`colmap_scene`]).
//! * A capture is read whole, normalised (`normalize`) and split by the held-out rule
//!   (`capture`): every 8th photo of the sorted names is held out. [`Dataset`] loads a
//!   split's frames and images together, the photos fitted to the pixel budget
//!   ([`photo_resize`]) and composited onto the background (`frame_image`, `frame_mask`).
//! * Around them: the backdrop a capture has or lacks ([`backdrop`]), the object's hull
//!   ([`object_hull`]), the camera paths of a capture (`orbit`, `spiral`), and the
//!   typed error ([`DatasetError`]).
//!
//! The NeRF-synthetic layout (e.g. `lego/`): `transforms_{split}.json` holds `camera_angle_x`
//! (horizontal field of view, radians) and `frames`, each with `file_path` (relative, without
//! the `.png` extension) and `transform_matrix`, the 4×4 Blender camera-to-world matrix
//! (`[row][col]`); `{split}/r_{i}.png` are 8-bit RGBA renders, transparent where there is no
//! object. Blender / OpenGL cameras look along their −Z axis with +Y up and +X right;
//! pytorch3d cameras look along +Z with +Y up and +X left (see [`nerf_core::camera`]).

pub mod backdrop;
pub(crate) mod camera_source;
pub(crate) mod capture;
pub(crate) mod capture_frame;
pub(crate) mod dataset_error;
pub(crate) mod frame_image;
pub(crate) mod frame_mask;
pub(crate) mod ngp_scene;
pub(crate) mod normalize;
pub mod object_hull;
pub(crate) mod orbit;
pub(crate) mod photo_fit;
pub mod photo_resize;
pub(crate) mod scene_format;
pub mod shared_view;
pub mod silhouette;
pub(crate) mod spiral;
pub(crate) mod split;
pub(crate) mod transforms_intrinsics;

/// Declares each scene format's module and lists its [`SceneFormat`] in [`SCENE_FORMATS`],
/// in the order [`SceneFormat::detect`] tries them: a new format is its own file, defining one
/// `SceneFormat`, and one line in the `scene_formats!` list below.
macro_rules! scene_formats {
    ($($module:ident::$format:ident),* $(,)?) => {
        $(pub mod $module;)*
        /// Every scene format `--data-dir` takes, in the order [`SceneFormat::detect`] tries
        /// them (the first a folder holds is its format).
        pub(crate) const SCENE_FORMATS: &[SceneFormat] = &[$($module::$format),*];
    };
}

scene_formats! {
    transforms::BLENDER,
    nerfstudio::NERFSTUDIO,
    llff::LLFF,
    colmap_scene::COLMAP,
}

use std::path::{Path, PathBuf};

use anyhow::Result;
use rayon::prelude::*;

use frame_mask::load_mask;
use nerf_core::camera::checks::check_photo_size;
use nerf_core::camera::Camera;
use nerf_core::image::RgbImage;

pub use capture::{
    read_capture_split, read_capture_split_with, CaptureInfo, Normalisation, SceneFormat,
    SplitProtocol,
};
pub use capture_frame::cameras_from_sfm;
pub use dataset_error::DatasetError;
pub use frame_image::*;
pub use frame_mask::PixelMask;
pub use normalize::SceneTransform;
pub use orbit::CaptureOrbit;
pub use spiral::CaptureSpiral;
pub use transforms::*;

/// The frames of `split` of the scene in `data_dir`, whatever its format
/// ([`SceneFormat::detect`]): a NeRF-synthetic split as `read_blender_split` reads it, or a
/// capture's, normalised by the transform its cameras give ([`read_capture_split`]; what was
/// applied is logged). Errors: see [`DatasetError`].
pub fn read_split(data_dir: &Path, split: Split) -> Result<Vec<Frame>, DatasetError> {
    Ok(read_split_with(data_dir, split, None)?.frames)
}

/// A split's frames and, for a capture, how they were normalised.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitFrames {
    /// The frames, as [`read_split`] orders them.
    pub frames: Vec<Frame>,
    /// `None` for a NeRF-synthetic scene, whose frame is used as it is.
    pub normalisation: Option<Normalisation>,
    /// For a capture, where its cameras came from and how it is split.
    pub capture: Option<CaptureInfo>,
}

/// [`read_split`] with a capture normalised by `stored` when given (the transform a model
/// was trained in: see [`read_capture_split_with`]); a NeRF-synthetic scene is never
/// normalised, so `stored` does not apply to it. Errors: see [`DatasetError`].
pub fn read_split_with(
    data_dir: &Path,
    split: Split,
    stored: Option<SceneTransform>,
) -> Result<SplitFrames, DatasetError> {
    split_frames(data_dir, split, stored).map_err(DatasetError::from_anyhow)
}

/// [`read_split_with`], its typed errors inside an `anyhow::Error`.
fn split_frames(
    data_dir: &Path,
    split: Split,
    stored: Option<SceneTransform>,
) -> Result<SplitFrames> {
    let format = SceneFormat::detect(data_dir);
    // Any kind of file under the name (a FIFO too: its reader refuses it, naming it).
    let blender_files = Split::ALL
        .iter()
        .any(|s| s.transforms_path(data_dir).exists());
    if format == transforms::BLENDER && data_dir.is_dir() && !blender_files {
        // A folder of something else (photos without cameras, a file named `sparse`): say
        // what a dataset folder holds rather than only that lego's file is missing.
        let sparse = data_dir.join("sparse");
        let message = format!(
            "{} holds no dataset nerf reads: expected {}{}; the {split} split of a \
             NeRF-synthetic scene reads transforms_{split}.json; photos without cameras go \
             through nerf process first; for lego, {DOWNLOAD_HINT}",
            data_dir.display(),
            SceneFormat::expected_files(),
            if sparse.exists() && !sparse.is_dir() {
                " (its `sparse` is a file, not a folder)"
            } else {
                ""
            }
        );
        return Err(DatasetError::no_dataset(data_dir, message).into());
    }
    if format == transforms::BLENDER {
        return Ok(SplitFrames {
            frames: read_blender_split(data_dir, split)?,
            normalisation: None,
            capture: None,
        });
    }
    let read = read_capture_split_with(data_dir, format, split, stored)?;
    let t = read.transform;
    let c = t.center;
    // Once: training reads the train split for its size, its frames and its cameras.
    capture::log_once(format!(
        "{}: {} capture, cameras from {}, {} of {} frames in the {split} split (held out: {}); normalised{}: centre ({:.3}, {:.3}, {:.3}) to the origin, mean camera up to +z, scale {:.4}",
        data_dir.display(),
        read.info.format.name(),
        read.info.camera_source,
        read.frames.len(),
        read.total_frames,
        read.info.protocol.describe(),
        if stored.is_some() { " as given" } else { "" },
        c.x,
        c.y,
        c.z,
        t.scale
    ));
    Ok(SplitFrames {
        frames: read.frames,
        normalisation: Some(Normalisation {
            applied: read.transform,
            from_cameras: read.from_cameras,
            depth_bounds: read.depth_bounds,
            from_sfm: read.from_sfm,
            sfm_residual: read.sfm_residual,
        }),
        capture: Some(read.info),
    })
}

/// Where to get the data, appended to errors about a missing scene directory or transforms file.
pub(crate) const DOWNLOAD_HINT: &str =
    "download the NeRF-synthetic lego scene (nerf_synthetic.zip \
    from the original NeRF project's data release) and pass --data-dir or set data.data_dir, \
    or run scripts/download_lego.sh (the default, ../shared/data/lego, is relative to the \
    working directory)";

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
    /// Per image, which pixels are used (`frame_mask`; `None`: all of them); empty when no
    /// frame has a mask.
    pub masks: Vec<Option<PixelMask>>,
    /// How a capture's cameras were normalised (`None` for a NeRF-synthetic scene): a model
    /// trained on this dataset lives in the frame `normalisation.applied` puts them in.
    pub normalisation: Option<Normalisation>,
    /// For a capture, where its cameras came from, how it is split and its photos' own size
    /// (`None` for a NeRF-synthetic scene).
    pub capture: Option<CaptureInfo>,
}

impl Dataset {
    /// Image `index`'s mask, when it has one.
    pub fn mask(&self, index: usize) -> Option<&PixelMask> {
        self.masks.get(index).and_then(Option::as_ref)
    }

    /// Reads a split's cameras ([`read_split`]) and loads every image ([`load_image`]) in
    /// parallel. The first failure is returned, naming its file (see [`DatasetError`]).
    pub fn load(
        data_dir: &Path,
        split: Split,
        width: usize,
        height: usize,
        white_background: bool,
    ) -> Result<Self, DatasetError> {
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
    ) -> Result<Self, DatasetError> {
        let size = (width, height);
        Self::load_first_with(data_dir, split, size, white_background, limit, None)
    }

    /// [`Dataset::load_first`] of `(width, height)` images with a capture normalised by
    /// `stored` when given ([`read_split_with`]): the transform a model was trained in.
    pub fn load_first_with(
        data_dir: &Path,
        split: Split,
        size: (usize, usize),
        white_background: bool,
        limit: Option<usize>,
        stored: Option<SceneTransform>,
    ) -> Result<Self, DatasetError> {
        let load = Self::load_images(data_dir, split, size, white_background, limit, stored);
        load.map_err(DatasetError::from_anyhow)
    }

    /// [`Dataset::load_first_with`], its typed errors inside an `anyhow::Error`.
    fn load_images(
        data_dir: &Path,
        split: Split,
        (width, height): (usize, usize),
        white_background: bool,
        limit: Option<usize>,
        stored: Option<SceneTransform>,
    ) -> Result<Self> {
        let SplitFrames {
            mut frames,
            normalisation,
            mut capture,
        } = read_split_with(data_dir, split, stored)?;
        frames.truncate(limit.unwrap_or(frames.len()));
        let (loaded, masks): (Vec<LoadedImage>, Vec<Option<PixelMask>>) = frames
            .par_iter()
            .map(|frame| {
                let image = load_frame_image(&frame.file_path, width, height, white_background)?;
                let mask = frame
                    .mask_path
                    .as_ref()
                    .map(|m| load_mask(m, &frame.file_path, image.source_size, (width, height)))
                    .transpose()?;
                Ok((image, mask))
            })
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .unzip();
        check_sizes_agree(&frames, &loaded)?;
        if let (Some(info), Some(first)) = (capture.as_mut(), loaded.first()) {
            info.photo_size = Some(first.source_size);
        }
        let masks = match masks.iter().any(Option::is_some) {
            true => {
                log::info!("{}", frame_mask::masks_line(data_dir, split, &frames));
                masks
            }
            false => Vec::new(),
        };
        let opaque = loaded.iter().filter(|l| !l.has_alpha).count();
        if opaque > 0 {
            log::warn!(
                "note: {opaque} of the {} images of {} have no alpha channel and are taken as \
                 opaque (no background compositing applies to them)",
                loaded.len(),
                data_dir.display()
            );
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
            masks,
            normalisation,
            capture,
        })
    }
}

/// An error naming the first image whose file size differs from the first frame's (a split's
/// images share one camera model, so a frame of another size cannot be scored against it), or
/// whose capture camera cannot describe it ([`check_photo_size`]).
fn check_sizes_agree(frames: &[Frame], loaded: &[LoadedImage]) -> Result<()> {
    let Some(first) = loaded.first() else {
        return Ok(());
    };
    for (frame, image) in frames.iter().zip(loaded) {
        if let Camera::Colmap(camera) = &frame.camera {
            check_photo_size(camera.size, image.source_size).map_err(|camera| {
                let message = format!("{}: {camera}", frame.file_path.display());
                DatasetError::Camera { camera, message }
            })?;
        }
        if image.source_size != first.source_size {
            let message = format!(
                "{} is {}x{}, but the split's images are {}x{} ({}): every image of a split must \
                 have the same size",
                frame.file_path.display(),
                image.source_size.0,
                image.source_size.1,
                first.source_size.0,
                first.source_size.1,
                frames[0].file_path.display()
            );
            return Err(DatasetError::photo(&frame.file_path, message).into());
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

/// The shared lego scene for tests, or `None` (with a message) when it is not on this machine.
#[cfg(test)]
pub(crate) fn test_lego_dir() -> Option<PathBuf> {
    let dir =
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join(default_data_dir("lego"));
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn whole_train_split_loads() {
        let Some(dir) = test_lego_dir() else { return };
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
    fn missing_directory_says_where_to_get_the_data() {
        let (dir, missing) = nerf_files::test_files::temp_file("lego");
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
        assert!(
            err.contains("holds no dataset") && !err.contains('\n'),
            "{err}"
        );
        // A file named `sparse` is not a COLMAP model, and the message says so.
        std::fs::write(dir.path().join("sparse"), b"").unwrap();
        let err = read_split(dir.path(), Split::Test).unwrap_err().to_string();
        assert!(
            err.contains("its `sparse` is a file, not a folder"),
            "{err}"
        );
    }
}
