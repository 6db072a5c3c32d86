//! `nerf process --images DIR --out OUT` (or `--video FILE`): photos (or frames of a video) to
//! a trainable capture through structure from motion. The photos (PNG and JPEG, sorted,
//! subfolders included) are copied to `OUT/images`, or frames chosen from the video
//! ([`crate::process::video_frames`]) written there; COLMAP runs feature extraction,
//! matching and mapping into `OUT/colmap` (each stage's output in `OUT/colmap/<stage>.log`).
//! The mapper may run several times ([`crate::process::mapper`]): the run the others agree
//! with best is kept, its model with the most registered images is written as nerfstudio's
//! `OUT/transforms.json` (less any image the other runs place elsewhere), which `--data-dir
//! OUT` then trains on.
//!
//! COLMAP is COLMAP 4 through the `pycolmap` wheel when Python imports it (`pip install
//! pycolmap`: no root, no build), else Debian's `colmap` program (3.8), run as a program (`colmap`
//! on `PATH`, or the executable named by `NERF_COLMAP`); `--sfm` chooses
//! ([`crate::process::colmap_run::Colmap`]). Why COLMAP 4 first: on the same photos its
//! matching and mapping take a fraction of 3.8's time, with cameras as accurate (measured:
//! docs/own-scene.md#structure-from-motion-measured).

pub mod colmap_run;
mod consensus;
pub mod external_tool;
pub mod frame_selection;
pub mod inputs;
pub mod mapper;
pub mod video_frames;

use std::ffi::OsStr;
use std::path::PathBuf;

use anyhow::{anyhow, bail, Context, Result};
use serde_json::{json, Map, Value};

use crate::process::colmap_run::{last_line, run_stage, Colmap, SfmChoice};
use crate::process::inputs::{
    check_names, check_photos_decode, copy_images, list_images, mark_finished, start_run,
};
use crate::process::mapper::{MapperRun, MappingOptions};
use nerf::core::camera::ColmapPose;
use nerf::core::lens::{ColmapCameraModel, Fisheye, LensDistortion, RadialTangential};
use nerf::io::colmap::{ColmapCameraRecord, ColmapModel};

pub use crate::process::mapper::MIN_REGISTERED;

/// Above this many images, [`Matcher::Auto`] matches sequentially instead of exhaustively
/// with the COLMAP program (a video's frames are always matched sequentially).
pub const EXHAUSTIVE_MAX_IMAGES: usize = 100;

/// With pycolmap, [`Matcher::Auto`] matches every pair up to this many images; above, ordered
/// images sequentially with retrieval pairs for loop closure, others by retrieval alone.
pub const PYCOLMAP_EXHAUSTIVE_MAX_IMAGES: usize = 50;

/// The retrieval pairs per image that close loops after sequential matching
/// (`--retrieval_neighbours` of `pycolmap_stages.py`).
pub const LOOP_NEIGHBOURS: usize = 15;

/// With pycolmap, sequential matching pairs each image with this many next ones (and their
/// quadratic steps: COLMAP's `quadratic_overlap`): with [`LOOP_NEIGHBOURS`], on 50 frames of a
/// phone walk-around, the cameras came out nearer exhaustive matching's in half its time
/// (measured: docs/own-scene.md#structure-from-motion-measured).
pub const PYCOLMAP_SEQUENTIAL_OVERLAP: usize = 15;

/// The retrieval pairs per image when retrieval alone pairs an unordered set.
pub const RETRIEVAL_NEIGHBOURS: usize = 20;

/// COLMAP's `exhaustive_matcher` matches images in blocks of this many (its default
/// `ExhaustiveMatching.block_size`), which the progress bar counts.
const EXHAUSTIVE_BLOCK: usize = 50;

/// How COLMAP pairs images for matching.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Matcher {
    /// Sequential for a video's frames; for photos exhaustive up to [`EXHAUSTIVE_MAX_IMAGES`]
    /// images, sequential above.
    Auto,
    /// Every pair (`exhaustive_matcher`): quadratic in the number of images.
    Exhaustive,
    /// Each image with its neighbours in name order and loop closures
    /// (`sequential_matcher`): for video frames and large ordered sets.
    Sequential,
    /// Each image with its most similar images by visual words (pycolmap only): sub-quadratic,
    /// for large unordered sets.
    Retrieval,
}

impl Matcher {
    /// The COLMAP command for `images` images (`ordered`: frames of a video, or photos
    /// numbered in order, [`numbered_in_order`]) and the retrieval neighbours it adds per
    /// image (0: none). `pycolmap`: whether COLMAP 4 through pycolmap runs it, which has
    /// retrieval; the program has none. An error for retrieval without pycolmap.
    pub fn command(
        self,
        images: usize,
        ordered: bool,
        pycolmap: bool,
    ) -> Result<(&'static str, usize)> {
        let loops = if pycolmap { LOOP_NEIGHBOURS } else { 0 };
        Ok(match self {
            Matcher::Exhaustive => ("exhaustive_matcher", 0),
            Matcher::Sequential => ("sequential_matcher", loops),
            Matcher::Retrieval if pycolmap => ("retrieval_matcher", RETRIEVAL_NEIGHBOURS),
            Matcher::Retrieval => bail!(
                "--matcher retrieval needs COLMAP 4 through pycolmap (`pip install pycolmap`), not the COLMAP program"
            ),
            Matcher::Auto if !pycolmap => {
                if ordered || images > EXHAUSTIVE_MAX_IMAGES {
                    ("sequential_matcher", 0)
                } else {
                    ("exhaustive_matcher", 0)
                }
            }
            Matcher::Auto if images <= PYCOLMAP_EXHAUSTIVE_MAX_IMAGES => ("exhaustive_matcher", 0),
            Matcher::Auto if ordered => ("sequential_matcher", LOOP_NEIGHBOURS),
            Matcher::Auto => ("retrieval_matcher", RETRIEVAL_NEIGHBOURS),
        })
    }
}

/// Whether photo names are numbered in order, as a camera or a video's frames name them
/// (`IMG_0412.JPG`, `frame_00001.jpg`, `templeR0001.png`, `0000.jpg`): every file stem is one
/// prefix followed by a number, and the numbers rise in sorted-name order. Such photos are
/// matched as a sequence (neighbours in order, and retrieval for the loop).
pub fn numbered_in_order(names: &[PathBuf]) -> bool {
    let split = |name: &PathBuf| -> Option<(String, u64)> {
        let stem = name.file_stem()?.to_str()?;
        let digits = stem.len() - stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
        if digits == 0 || digits > 18 {
            return None;
        }
        let (prefix, number) = stem.split_at(stem.len() - digits);
        let folder = name.parent().map(|p| p.to_string_lossy().into_owned());
        Some((
            format!("{}/{prefix}", folder.unwrap_or_default()),
            number.parse().ok()?,
        ))
    };
    let Some(parts) = names.iter().map(split).collect::<Option<Vec<_>>>() else {
        return false;
    };
    names.len() >= 2
        && parts
            .windows(2)
            .all(|w| w[0].0 == w[1].0 && w[0].1 < w[1].1)
}

/// Where the photos come from.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// A folder of photos, copied.
    Images(PathBuf),
    /// A video, of which `frames` frames are chosen ([`crate::process::video_frames`]).
    Video {
        /// The video file.
        file: PathBuf,
        /// Frames to keep, at least 3.
        frames: usize,
    },
}

/// How COLMAP extracts SIFT features: matching compares every feature of one image with every
/// feature of the other, so its time grows with the square of the features kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeatureOptions {
    /// Most features kept per image (`--SiftExtraction.max_num_features`; the largest-scale
    /// ones are kept).
    pub max_features: usize,
    /// Photos larger than this (pixels, the longer side) are downscaled for extraction
    /// (`--SiftExtraction.max_image_size`); `None`: [`PYCOLMAP_MAX_IMAGE_SIZE`] with pycolmap,
    /// [`DEFAULT_MAX_IMAGE_SIZE`] with the program.
    pub max_image_size: Option<usize>,
}

impl Default for FeatureOptions {
    fn default() -> Self {
        Self {
            max_features: DEFAULT_MAX_FEATURES,
            max_image_size: None,
        }
    }
}

/// [`FeatureOptions::max_features`] by default.
pub const DEFAULT_MAX_FEATURES: usize = 8192;

/// [`FeatureOptions::max_image_size`] by default with the COLMAP program.
pub const DEFAULT_MAX_IMAGE_SIZE: usize = 3200;

/// [`FeatureOptions::max_image_size`] by default with pycolmap: features from photos at most
/// this large place the cameras as accurately in a fraction of the time (measured:
/// docs/own-scene.md#structure-from-motion-measured).
pub const PYCOLMAP_MAX_IMAGE_SIZE: usize = 1600;

/// The camera model COLMAP fits with pycolmap: COLMAP 4's mapper registers 2 or 3 images of
/// the temple ring with `OPENCV` or `RADIAL` and all of them with `SIMPLE_RADIAL` (measured:
/// docs/own-scene.md#structure-from-motion-measured).
pub const PYCOLMAP_CAMERA_MODEL: &str = "SIMPLE_RADIAL";

/// The camera model COLMAP fits with the program.
pub const PROGRAM_CAMERA_MODEL: &str = "OPENCV";

/// What [`process`] is asked to do.
#[derive(Debug, Clone)]
pub struct ProcessOptions {
    /// The photos.
    pub source: Source,
    /// The capture folder written.
    pub out: PathBuf,
    /// How images are paired for matching.
    pub matcher: Matcher,
    /// A COLMAP vocabulary tree file: with it, sequential matching also detects loops
    /// (`--SequentialMatching.loop_detection 1`); Debian's colmap ships none.
    pub vocab_tree: Option<PathBuf>,
    /// How features are extracted.
    pub features: FeatureOptions,
    /// How the mapper runs; `runs: None`: 1 with pycolmap, 3 with the program.
    pub mapping: MappingOptions,
    /// Which COLMAP runs.
    pub sfm: SfmChoice,
}

/// How long one COLMAP stage ran.
#[derive(Debug, Clone, PartialEq)]
pub struct StageTime {
    /// COLMAP's command (`feature_extractor`, ...).
    pub stage: &'static str,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// What [`process`] made.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessSummary {
    /// Photos found and copied, or frames written from the video.
    pub images: usize,
    /// For a video, how its frames were chosen.
    pub video: Option<crate::process::video_frames::FrameChoice>,
    /// Images in the chosen model.
    pub registered: usize,
    /// Images of the chosen model left out of `transforms.json` because the other mapper
    /// runs placed them elsewhere, with that disagreement (fraction of the camera spread).
    pub left_out: Vec<(String, f64)>,
    /// The frames of `transforms.json`: `registered` less `left_out`.
    pub frames: usize,
    /// Each mapper run.
    pub mapper_runs: Vec<MapperRun>,
    /// The fraction of the registered photos' border pixels that are white
    /// ([`nerf::io::dataset::backdrop::white_border_fraction`]); `None` when they could not
    /// be read.
    pub white_border: Option<f64>,
    /// The chosen COLMAP model's folder.
    pub model_dir: PathBuf,
    /// The `transforms.json` written.
    pub transforms: PathBuf,
    /// Each COLMAP stage's time, in order.
    pub stages: Vec<StageTime>,
}

/// Runs the whole pipeline of the module doc: lists and copies the photos (or writes the
/// video's chosen frames), runs COLMAP's feature extraction and matching, maps
/// ([`crate::process::mapper::map`]), and writes `OUT/transforms.json` (atomically, last,
/// so a failed run leaves none). One-line errors: no photos, a photo whose name COLMAP cannot
/// keep or that does not decode, not a video, ffmpeg or COLMAP missing, a vocabulary tree that
/// is not a file, a finished run's outputs in `OUT`, a stage that failed (naming its log),
/// fewer than [`MIN_REGISTERED`] images registered, a camera model nerfstudio cannot hold.
/// Until the input checks pass, `OUT` is left as it was; from then until `transforms.json` is
/// written it holds the unfinished-run marker, and a re-run replaces what it left
/// ([`crate::process::inputs::start_run`]).
pub fn process(options: &ProcessOptions) -> Result<ProcessSummary> {
    let ProcessOptions {
        source,
        out,
        matcher,
        vocab_tree,
        features,
        mapping,
        sfm,
    } = options;
    let photos = match source {
        Source::Images(dir) => {
            let names = list_images(dir, Some(out))?;
            check_names(dir, &names)?;
            check_photos_decode(dir, &names)?;
            Some(names)
        }
        Source::Video { file, frames } => {
            if !file.is_file() {
                bail!("--video {}: not a file", file.display());
            }
            if *frames < MIN_REGISTERED {
                bail!("--frames {frames}: at least {MIN_REGISTERED} frames are needed");
            }
            None
        }
    };
    let ffmpeg = crate::process::video_frames::ffmpeg_program();
    if photos.is_none() {
        crate::process::video_frames::check_ffmpeg(&ffmpeg)?;
    }
    let images = out.join("images");
    let colmap = out.join("colmap");
    let sfm = Colmap::find(*sfm, &colmap)?;
    matcher.command(0, false, sfm.is_pycolmap())?;
    if let Some(tree) = vocab_tree {
        if !tree.is_file() {
            bail!("--vocab-tree {}: not a file", tree.display());
        }
    }
    // A file ffmpeg cannot read as a video is named before OUT is touched.
    let probe = match source {
        Source::Video { file, .. } => Some(crate::process::video_frames::probe(&ffmpeg, file)?),
        Source::Images(_) => None,
    };
    start_run(out)?;
    let (names, video) = match source {
        Source::Images(dir) => {
            let names = photos.unwrap_or_default();
            log::info!(
                "{} photos in {}: copying them to {}",
                names.len(),
                dir.display(),
                images.display()
            );
            copy_images(dir, &names, &images)?;
            (names, None)
        }
        Source::Video { file, frames } => {
            let probe = probe.context("a video's probe")?;
            std::fs::create_dir_all(out)
                .with_context(|| format!("cannot create {}", out.display()))?;
            let choice = crate::process::video_frames::extract_frames(
                &ffmpeg, file, &probe, *frames, &images,
            )?;
            log::info!(
                "wrote {} frames of {} to {} (the sharpest of each stretch of {} candidates over {:.1} s)",
                choice.frames,
                file.display(),
                images.display(),
                choice.candidates,
                choice.duration
            );
            (list_images(&images, None)?, Some(choice))
        }
    };
    std::fs::create_dir_all(&colmap)
        .with_context(|| format!("cannot create {}", colmap.display()))?;
    sfm.write_script()?;

    let database = colmap.join("database.db");
    let n = names.len();
    // The program has no retrieval to close a loop: it keeps matching numbered photos
    // exhaustively (up to EXHAUSTIVE_MAX_IMAGES), as before.
    let ordered = video.is_some() || (sfm.is_pycolmap() && numbered_in_order(&names));
    // COLMAP's pair lists split lines at spaces: such names get no retrieval pairs, said why.
    let awkward = names.iter().find(|n| {
        let s = n.to_string_lossy();
        s.contains(char::is_whitespace) || s.starts_with('#')
    });
    let retrieval = sfm.is_pycolmap() && (awkward.is_none() || *matcher == Matcher::Retrieval);
    if let (Some(name), true) = (awkward, sfm.is_pycolmap() && !retrieval) {
        log::warn!(
            "{}: a photo name with a space or a leading '#', which COLMAP's pair lists cannot hold: matching without retrieval pairs",
            name.display()
        );
    }
    let (matcher, neighbours) = matcher.command(n, ordered, retrieval)?;
    log::info!(
        "structure from motion: {}; {n} images{}, matched by {matcher}{}",
        sfm.describe(),
        if ordered { " in order" } else { "" },
        if neighbours > 0 {
            format!(" with {neighbours} retrieval pairs per image")
        } else {
            String::new()
        }
    );
    let neighbours_text = neighbours.to_string();
    let overlap_text = PYCOLMAP_SEQUENTIAL_OVERLAP.to_string();
    let mut pairing: Vec<&std::ffi::OsStr> = Vec::new();
    if neighbours > 0 {
        pairing.extend(["--retrieval_neighbours", neighbours_text.as_str()].map(OsStr::new));
    }
    if sfm.is_pycolmap() && matcher == "sequential_matcher" {
        pairing.extend(["--SequentialMatching.overlap", overlap_text.as_str()].map(OsStr::new));
    }
    let loops: Vec<&std::ffi::OsStr> = match vocab_tree {
        Some(tree) if sfm.is_pycolmap() => {
            log::warn!(
                "--vocab-tree {} is for the COLMAP program; with pycolmap, retrieval pairs close the loops (COLMAP 4 reads only faiss trees)",
                tree.display()
            );
            Vec::new()
        }
        Some(tree) if matcher == "sequential_matcher" => vec![
            "--SequentialMatching.loop_detection".as_ref(),
            "1".as_ref(),
            "--SequentialMatching.vocab_tree_path".as_ref(),
            tree.as_os_str(),
        ],
        Some(tree) => {
            log::warn!(
                "--vocab-tree {} is used by sequential matching only; {matcher} runs without it",
                tree.display()
            );
            Vec::new()
        }
        None => Vec::new(),
    };
    let blocks = n.div_ceil(EXHAUSTIVE_BLOCK).pow(2);
    let max_features = features.max_features.to_string();
    let (camera_model, default_size) = if sfm.is_pycolmap() {
        (PYCOLMAP_CAMERA_MODEL, PYCOLMAP_MAX_IMAGE_SIZE)
    } else {
        (PROGRAM_CAMERA_MODEL, DEFAULT_MAX_IMAGE_SIZE)
    };
    let max_image_size = features.max_image_size.unwrap_or(default_size).to_string();
    let stages: [(&'static str, Vec<&std::ffi::OsStr>, usize); 2] = [
        (
            "feature_extractor",
            vec![
                "--database_path".as_ref(),
                database.as_os_str(),
                "--image_path".as_ref(),
                images.as_os_str(),
                "--ImageReader.single_camera".as_ref(),
                "1".as_ref(),
                "--ImageReader.camera_model".as_ref(),
                camera_model.as_ref(),
                "--SiftExtraction.use_gpu".as_ref(),
                "0".as_ref(),
                "--SiftExtraction.max_num_features".as_ref(),
                max_features.as_ref(),
                "--SiftExtraction.max_image_size".as_ref(),
                max_image_size.as_ref(),
            ],
            n,
        ),
        (
            matcher,
            vec![
                "--database_path".as_ref(),
                database.as_os_str(),
                "--SiftMatching.use_gpu".as_ref(),
                "0".as_ref(),
            ]
            .into_iter()
            .chain(loops)
            .chain(pairing)
            .collect(),
            if matcher == "exhaustive_matcher" {
                blocks
            } else {
                n
            },
        ),
    ];
    let mut times = Vec::new();
    for (stage, args, steps) in stages {
        let log = colmap.join(format!("{stage}.log"));
        let (status, seconds) = run_stage(&sfm, stage, &args, &log, steps as u64)?;
        if !status.success() {
            bail!(
                "COLMAP's {stage} failed ({status}): see {} (its last line: {})",
                log.display(),
                last_line(&log)
            );
        }
        log::info!("COLMAP {stage}: {seconds:.1} s (log: {})", log.display());
        times.push(StageTime { stage, seconds });
    }

    let mapping = crate::process::mapper::map(&sfm, &colmap, &database, &images, n, mapping)?;
    times.push(StageTime {
        stage: "mapper",
        seconds: mapping.runs.iter().map(|r| r.seconds).sum(),
    });
    times.push(StageTime {
        stage: "refinement",
        seconds: mapping.refine_seconds,
    });
    let mapper_log = crate::process::mapper::run_log(&colmap, 0);
    let too_few = |registered: usize| {
        anyhow!(
            "COLMAP registered {registered} of {n} images; at least {MIN_REGISTERED} are needed: take photos with more overlap and texture (see {})",
            mapper_log.display()
        )
    };
    if mapping.chosen.is_none() {
        return Err(too_few(0));
    }
    let (model_dir, mut model) = nerf::io::colmap::find_model(&colmap)?;
    let registered = model.images.len();
    if registered < MIN_REGISTERED {
        return Err(too_few(registered));
    }
    if !mapping.outliers.is_empty() {
        let listed: Vec<String> = mapping
            .outliers
            .iter()
            .map(|(name, d)| format!("{name} ({:.1}%)", 100.0 * d))
            .collect();
        log::warn!(
            "the mapper runs placed {} of the kept run's images elsewhere (by a median of, as a share of the camera spread): {}; they are left out of transforms.json",
            listed.len(),
            listed.join(", ")
        );
        model
            .images
            .retain(|image| !mapping.outliers.iter().any(|(name, _)| name == &image.name));
    }
    let frames = model.images.len();
    if frames < MIN_REGISTERED {
        return Err(too_few(frames));
    }
    let kept: Vec<PathBuf> = model
        .images
        .iter()
        .map(|i| PathBuf::from(&i.name))
        .collect();
    let white_border = nerf::io::dataset::backdrop::white_border_fraction(&images, &kept)
        .map_err(|e| log::warn!("cannot judge the photos' backdrop: {e:#}"))
        .ok();
    let transforms = transforms_json(&model)?;
    let text = serde_json::to_string_pretty(&transforms)? + "\n";
    let transforms_path = out.join("transforms.json");
    nerf::io::output::write_text(&transforms_path, &text)?;
    mark_finished(out)?;
    let unregistered = n - registered.min(n);
    log::info!(
        "COLMAP registered {registered} of {n} images (model {}){}",
        model_dir.display(),
        if unregistered > 0 {
            format!("; the {unregistered} it did not register are left out of transforms.json")
        } else {
            String::new()
        }
    );
    Ok(ProcessSummary {
        images: n,
        video,
        registered,
        left_out: mapping.outliers,
        frames,
        mapper_runs: mapping.runs,
        white_border,
        model_dir,
        transforms: transforms_path,
        stages: times,
    })
}

/// nerfstudio's intrinsics keys for a COLMAP camera: `camera_model` OPENCV (from
/// SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, and FULL_OPENCV without its
/// rational terms) or OPENCV_FISHEYE, `fl_x fl_y cx cy w h` and the distortion. An error
/// naming the model when nerfstudio cannot hold it.
pub fn intrinsics_json(camera: &ColmapCameraRecord) -> Result<Map<String, Value>> {
    let model = ColmapCameraModel::from_name(&camera.model)?;
    let (focal, principal, distortion) = model
        .intrinsics(&camera.params)
        .with_context(|| format!("COLMAP camera {}", camera.id))?;
    let mut keys = Map::new();
    let mut put = |k: &str, v: Value| {
        keys.insert(k.to_string(), v);
    };
    let name = if distortion.is_fisheye() {
        "OPENCV_FISHEYE"
    } else {
        "OPENCV"
    };
    put("camera_model", json!(name));
    put("fl_x", json!(focal[0]));
    put("fl_y", json!(focal[1]));
    put("cx", json!(principal[0]));
    put("cy", json!(principal[1]));
    put("w", json!(camera.width));
    put("h", json!(camera.height));
    let (k, p) = match distortion {
        LensDistortion::None(_) => ([0.0; 4], [0.0; 2]),
        LensDistortion::RadialTangential(RadialTangential {
            numerator,
            denominator,
            tangential,
        }) => {
            if denominator.iter().any(|&b| b != 0.0) {
                bail!(
                    "COLMAP camera {} is {} with rational terms k4..k6 {denominator:?}, which nerfstudio's OPENCV cannot hold",
                    camera.id,
                    camera.model
                );
            }
            (numerator, tangential)
        }
        LensDistortion::Fisheye(Fisheye { k }) => (k, [0.0; 2]),
        _ => bail!(
            "COLMAP camera {} is {}, a lens nerfstudio's OPENCV and OPENCV_FISHEYE cannot hold",
            camera.id,
            camera.model
        ),
    };
    put("k1", json!(k[0]));
    put("k2", json!(k[1]));
    if name == "OPENCV_FISHEYE" || k[2] != 0.0 || k[3] != 0.0 {
        put("k3", json!(k[2]));
        put("k4", json!(k[3]));
    }
    put("p1", json!(p[0]));
    put("p2", json!(p[1]));
    Ok(keys)
}

/// nerfstudio's `transforms.json` of a COLMAP model: the intrinsics at the top when every
/// image shares one camera (else in each frame), and per registered image, sorted by name,
/// `file_path` `images/<name>` and `transform_matrix` ([`ColmapPose::opengl_camera_to_world`]).
pub fn transforms_json(model: &ColmapModel) -> Result<Value> {
    let mut images: Vec<_> = model.images.iter().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let first = images
        .first()
        .ok_or_else(|| anyhow!("the COLMAP model has no images"))?;
    let shared = images.iter().all(|i| i.camera_id == first.camera_id);
    let mut top = if shared {
        intrinsics_json(model.camera_of(first))?
    } else {
        Map::new()
    };
    let frames = images
        .iter()
        .map(|image| {
            let pose = ColmapPose::from_quaternion(image.qvec, image.tvec)
                .with_context(|| format!("COLMAP image {}", image.name))?;
            let mut frame = if shared {
                Map::new()
            } else {
                intrinsics_json(model.camera_of(image))?
            };
            frame.insert("file_path".into(), json!(format!("images/{}", image.name)));
            frame.insert(
                "transform_matrix".into(),
                json!(pose.opengl_camera_to_world()),
            );
            Ok(Value::Object(frame))
        })
        .collect::<Result<Vec<_>>>()?;
    top.insert("frames".into(), Value::Array(frames));
    Ok(Value::Object(top))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbered_names_are_in_order() {
        let names = |list: &[&str]| list.iter().map(PathBuf::from).collect::<Vec<_>>();
        for ordered in [
            &["IMG_0412.JPG", "IMG_0413.JPG", "IMG_0415.JPG"][..],
            &["frame_00001.jpg", "frame_00002.jpg"],
            &["templeR0001.png", "templeR0002.png", "templeR0047.png"],
            &["0000.jpg", "0001.jpg", "0024.jpg"],
            &["a/001.jpg", "a/002.jpg"],
        ] {
            assert!(numbered_in_order(&names(ordered)), "{ordered:?}");
        }
        for unordered in [
            &["IMG_0412.JPG"][..],
            &["beach.jpg", "house.jpg"],
            &["a_01.jpg", "b_02.jpg"],
            &["a/001.jpg", "b/002.jpg"],
            &["x_1.jpg", "x_10.jpg", "x_2.jpg"],
            &["frame_01.jpg", "frame_01b.jpg"],
        ] {
            assert!(!numbered_in_order(&names(unordered)), "{unordered:?}");
        }
    }

    #[test]
    fn matchers_by_backend_and_size() {
        let auto = |n, ordered, py| Matcher::Auto.command(n, ordered, py).unwrap();
        // pycolmap: every pair for small sets, a sequence with loop pairs, retrieval otherwise.
        assert_eq!(auto(50, true, true), ("exhaustive_matcher", 0));
        assert_eq!(
            auto(67, true, true),
            ("sequential_matcher", LOOP_NEIGHBOURS)
        );
        assert_eq!(
            auto(67, false, true),
            ("retrieval_matcher", RETRIEVAL_NEIGHBOURS)
        );
        // The program as before: no retrieval.
        assert_eq!(auto(67, false, false), ("exhaustive_matcher", 0));
        assert_eq!(auto(67, true, false), ("sequential_matcher", 0));
        assert_eq!(auto(101, false, false), ("sequential_matcher", 0));
        assert_eq!(
            Matcher::Sequential.command(10, false, false).unwrap(),
            ("sequential_matcher", 0)
        );
        let e = Matcher::Retrieval.command(10, false, false).unwrap_err();
        assert!(e.to_string().contains("pycolmap"), "{e}");
    }

    #[test]
    fn camera_to_world_round_trips() {
        let pose = ColmapPose::from_quaternion([0.9, 0.1, -0.3, 0.2], [0.5, -1.0, 2.0]).unwrap();
        let m = pose.opengl_camera_to_world();
        let rows = [m[0], m[1], m[2]];
        let back = ColmapPose::from_opengl_camera_to_world(rows);
        assert!(back.rotation.abs_diff_eq(pose.rotation, 1e-12));
        assert!((back.translation - pose.translation).abs().max_element() < 1e-12);
        assert_eq!(m[3], [0.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn intrinsics_convert_or_refuse() {
        let camera = |model: &str, params: Vec<f64>| ColmapCameraRecord {
            id: 1,
            model: model.into(),
            width: 40,
            height: 30,
            params,
        };
        let pinhole =
            intrinsics_json(&camera("SIMPLE_RADIAL", vec![50.0, 20.0, 15.0, 0.1])).unwrap();
        assert_eq!(pinhole["camera_model"], "OPENCV");
        assert_eq!(pinhole["fl_y"], 50.0);
        assert_eq!(pinhole["k1"], 0.1);
        let fisheye = intrinsics_json(&camera(
            "OPENCV_FISHEYE",
            vec![50.0, 51.0, 20.0, 15.0, 0.1, 0.2, 0.3, 0.4],
        ))
        .unwrap();
        assert_eq!(fisheye["camera_model"], "OPENCV_FISHEYE");
        assert_eq!(fisheye["k4"], 0.4);
        let mut full = vec![
            50.0, 51.0, 20.0, 15.0, 0.1, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        ];
        assert!(intrinsics_json(&camera("FULL_OPENCV", full.clone())).is_ok());
        full[9] = 0.5;
        let e = intrinsics_json(&camera("FULL_OPENCV", full)).unwrap_err();
        assert!(e.to_string().contains("rational"), "{e}");
        let fov = vec![50.0, 51.0, 20.0, 15.0, 0.9];
        let e = intrinsics_json(&camera("FOV", fov)).unwrap_err();
        assert!(e.to_string().contains("is FOV, a lens nerfstudio"), "{e}");
    }
}
