//! `nerf process --images DIR --out OUT`: a folder of photos to a trainable capture through
//! structure from motion. The photos (PNG and JPEG, sorted, subfolders included) are copied to
//! `OUT/images`; COLMAP's command line runs feature extraction, matching and mapping into
//! `OUT/colmap` (each stage's output in `OUT/colmap/<stage>.log`); the model with the most
//! registered images is picked and written as nerfstudio's `OUT/transforms.json`, which
//! `--data-dir OUT` then trains on.
//!
//! COLMAP is Debian's `colmap` package (`sudo apt-get install colmap`), run as a program
//! (`colmap` on `PATH`, or the executable named by `NERF_COLMAP`), not the `pycolmap` wheel:
//! its command line is stable across releases, it extracts SIFT features on the CPU (no GPU or
//! display needed, with `QT_QPA_PLATFORM=offscreen`), and it puts no Python in the path.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use serde_json::{json, Map, Value};

use crate::core::camera_colmap::{ColmapCameraModel, ColmapPose};
use crate::core::distortion::LensDistortion;
use crate::io::colmap::{ColmapCamera, ColmapModel};
use crate::io::progress::progress_bar;

/// The environment variable naming the COLMAP executable (default: `colmap` on `PATH`).
pub const COLMAP_ENV: &str = "NERF_COLMAP";

/// Fewest registered images written as a capture.
pub const MIN_REGISTERED: usize = 3;

/// Runs of COLMAP's mapper at most: a run that registers under half of the photos is
/// repeated with another `--random_seed`, the best model kept.
pub const MAPPER_ATTEMPTS: u64 = 3;

/// Above this many images, [`Matcher::Auto`] matches sequentially instead of exhaustively.
pub const EXHAUSTIVE_MAX_IMAGES: usize = 100;

/// COLMAP's `exhaustive_matcher` matches images in blocks of this many (its default
/// `ExhaustiveMatching.block_size`), which the progress bar counts.
const EXHAUSTIVE_BLOCK: usize = 50;

/// Extensions of the photos taken (compared without case).
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// How COLMAP pairs images for matching.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Matcher {
    /// Exhaustive up to [`EXHAUSTIVE_MAX_IMAGES`] images, sequential above.
    Auto,
    /// Every pair (`exhaustive_matcher`): quadratic in the number of images.
    Exhaustive,
    /// Each image with its neighbours in name order and loop closures
    /// (`sequential_matcher`): for video frames and large ordered sets.
    Sequential,
}

impl Matcher {
    /// The COLMAP command for `images` images.
    pub fn command(self, images: usize) -> &'static str {
        match self {
            Matcher::Exhaustive => "exhaustive_matcher",
            Matcher::Sequential => "sequential_matcher",
            Matcher::Auto if images > EXHAUSTIVE_MAX_IMAGES => "sequential_matcher",
            Matcher::Auto => "exhaustive_matcher",
        }
    }
}

/// What [`process`] is asked to do.
#[derive(Debug, Clone)]
pub struct ProcessOptions {
    /// The folder of photos.
    pub images: PathBuf,
    /// The capture folder written.
    pub out: PathBuf,
    /// How images are paired for matching.
    pub matcher: Matcher,
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
    /// Photos found and copied.
    pub images: usize,
    /// Images in the chosen model (the frames of `transforms.json`).
    pub registered: usize,
    /// The chosen COLMAP model's folder.
    pub model_dir: PathBuf,
    /// The `transforms.json` written.
    pub transforms: PathBuf,
    /// Each COLMAP stage's time, in order.
    pub stages: Vec<StageTime>,
}

/// The photos under `dir` (PNG and JPEG by extension, in subfolders too, hidden entries and
/// `skip` left out) as paths relative to `dir`, sorted. One-line errors: `dir` not a folder,
/// or no photos in it.
pub fn list_images(dir: &Path, skip: Option<&Path>) -> Result<Vec<PathBuf>> {
    if !dir.is_dir() {
        bail!("--images {}: not a folder", dir.display());
    }
    let mut found = Vec::new();
    let mut pending = vec![PathBuf::new()];
    while let Some(relative) = pending.pop() {
        let folder = dir.join(&relative);
        let entries = std::fs::read_dir(&folder)
            .with_context(|| format!("cannot list {}", folder.display()))?;
        for entry in entries {
            let entry = entry.with_context(|| format!("cannot list {}", folder.display()))?;
            let name = entry.file_name();
            if name.to_string_lossy().starts_with('.') {
                continue;
            }
            let path = entry.path();
            let child = relative.join(&name);
            if path.is_dir() {
                let skipped = skip.is_some_and(|s| same_file(&path, s));
                if !skipped {
                    pending.push(child);
                }
            } else if path.is_file() && is_image_name(&path) {
                found.push(child);
            }
        }
    }
    if found.is_empty() {
        bail!(
            "no images in {}: nerf process takes PNG and JPEG photos (.png, .jpg, .jpeg), in subfolders too",
            dir.display()
        );
    }
    found.sort();
    Ok(found)
}

/// Whether `a` and `b` name the same existing file or folder.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Whether `path` has a photo's extension.
fn is_image_name(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The COLMAP executable: `$NERF_COLMAP` when set, else `colmap` (looked up on `PATH`).
pub fn colmap_program() -> PathBuf {
    std::env::var_os(COLMAP_ENV)
        .filter(|v| !v.is_empty())
        .map_or_else(|| PathBuf::from("colmap"), PathBuf::from)
}

/// A COLMAP command with its environment: no display (`QT_QPA_PLATFORM=offscreen`), no input.
fn colmap_command(program: &Path, stage: &str) -> Command {
    let mut command = Command::new(program);
    command
        .arg(stage)
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null());
    command
}

/// Checks that `program` runs (`colmap help`); the one-line error says that COLMAP is
/// missing and how to install it.
pub fn check_colmap(program: &Path) -> Result<()> {
    let run = colmap_command(program, "help")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    match run {
        Ok(_) => Ok(()),
        Err(e) => {
            let which = match std::env::var_os(COLMAP_ENV).filter(|v| !v.is_empty()) {
                Some(_) => format!("{COLMAP_ENV}={}", program.display()),
                None => format!("`{}` on PATH", program.display()),
            };
            bail!(
                "COLMAP is missing: cannot run {which} ({e}); install it with `sudo apt-get install colmap` (Debian/Ubuntu) or set {COLMAP_ENV} to the colmap executable"
            )
        }
    }
}

/// The outputs of an earlier run in `out` that [`process`] refuses to replace.
fn earlier_outputs(out: &Path) -> Vec<&'static str> {
    ["transforms.json", "images", "colmap"]
        .into_iter()
        .filter(|name| out.join(name).symlink_metadata().is_ok())
        .collect()
}

/// Copies each of `names` (relative to `from`) to the same relative path under `to`, each
/// through a temporary file renamed into place, so no half-copied photo is ever there.
pub fn copy_images(from: &Path, names: &[PathBuf], to: &Path) -> Result<()> {
    let bar = progress_bar(names.len() as u64, "copying images");
    for name in names {
        let target = to.join(name);
        let folder = target.parent().unwrap_or(to);
        std::fs::create_dir_all(folder)
            .with_context(|| format!("cannot create {}", folder.display()))?;
        let file_name = target.file_name().unwrap_or_default().to_string_lossy();
        let temp = folder.join(format!(".{file_name}.{}.tmp", std::process::id()));
        let source = from.join(name);
        let copied = std::fs::copy(&source, &temp).and_then(|_| std::fs::rename(&temp, &target));
        if let Err(e) = copied {
            let _ = std::fs::remove_file(&temp);
            bail!(
                "cannot copy {} to {}: {e}",
                source.display(),
                target.display()
            );
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(())
}

/// Progress a line of COLMAP's output reports: `(done, of)` steps, where `of` is `None` when
/// the line does not say it. Feature extraction: `Processed file [i/N]`; exhaustive matching:
/// `Matching block [a/A, b/B]`; sequential matching: `Matching image [i/N]`; mapping:
/// `Registering image #id (n)` (n images registered so far) and the initial pair (2).
pub fn stage_progress(line: &str) -> Option<(u64, Option<u64>)> {
    let bracket = |rest: &str| -> Option<Vec<(u64, u64)>> {
        let inner = rest.trim_start().strip_prefix('[')?.split(']').next()?;
        inner
            .split(',')
            .map(|part| {
                let (i, n) = part.trim().split_once('/')?;
                Some((i.trim().parse().ok()?, n.trim().parse().ok()?))
            })
            .collect()
    };
    let line = line.trim();
    if let Some(rest) = line
        .strip_prefix("Processed file")
        .or_else(|| line.strip_prefix("Matching image"))
    {
        let &[(i, n)] = bracket(rest)?.as_slice() else {
            return None;
        };
        return Some((i, Some(n)));
    }
    if let Some(rest) = line.strip_prefix("Matching block") {
        let &[(a, na), (b, nb)] = bracket(rest)?.as_slice() else {
            return None;
        };
        return Some(((a.saturating_sub(1)) * nb + b, Some(na * nb)));
    }
    if let Some(rest) = line.strip_prefix("Registering image #") {
        let count = rest.split_once('(')?.1.split_once(')')?.0;
        return Some((count.trim().parse().ok()?, None));
    }
    line.starts_with("Initializing with image pair")
        .then_some((2, None))
}

/// Runs `colmap <stage> <args>` with its stdout and stderr written to `log`, a progress bar
/// of `steps` steps named after the stage fed from its output ([`stage_progress`]), and
/// returns its exit status and the seconds it ran. An error when it cannot start.
fn run_stage(
    program: &Path,
    stage: &'static str,
    args: &[&std::ffi::OsStr],
    log: &Path,
    steps: u64,
) -> Result<(ExitStatus, f64)> {
    let start = Instant::now();
    let file = File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let writer = Arc::new(Mutex::new(BufWriter::new(file)));
    let mut child = colmap_command(program, stage)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| anyhow!("cannot run COLMAP's {stage} ({}): {e}", program.display()))?;
    let bar = progress_bar(steps.max(1), &format!("COLMAP {stage}"));
    let done = Arc::new(Mutex::new(0u64));
    let readers: Vec<Box<dyn Read + Send>> = vec![
        Box::new(child.stdout.take().expect("piped stdout")),
        Box::new(child.stderr.take().expect("piped stderr")),
    ];
    let threads: Vec<_> = readers
        .into_iter()
        .map(|stream| {
            let (writer, bar, done) = (writer.clone(), bar.clone(), done.clone());
            std::thread::spawn(move || {
                for line in BufReader::new(stream).split(b'\n').map_while(|l| l.ok()) {
                    let mut w = writer.lock().unwrap_or_else(|e| e.into_inner());
                    let _ = w.write_all(&line).and_then(|()| w.write_all(b"\n"));
                    drop(w);
                    if let Some((now, _)) = stage_progress(&String::from_utf8_lossy(&line)) {
                        let mut done = done.lock().unwrap_or_else(|e| e.into_inner());
                        let now = now.min(steps);
                        if now > *done {
                            bar.inc(now - *done);
                            *done = now;
                        }
                    }
                }
            })
        })
        .collect();
    let status = child.wait();
    for t in threads {
        let _ = t.join();
    }
    bar.finish_and_clear();
    let flushed = writer.lock().unwrap_or_else(|e| e.into_inner()).flush();
    let status = status.with_context(|| format!("COLMAP's {stage} did not finish"))?;
    flushed.with_context(|| format!("cannot write {}", log.display()))?;
    Ok((status, start.elapsed().as_secs_f64()))
}

/// The last line of `log` that is not blank, for an error message.
fn last_line(log: &Path) -> String {
    std::fs::read(log)
        .map(|bytes| {
            String::from_utf8_lossy(&bytes)
                .lines()
                .rev()
                .map(str::trim)
                .find(|l| !l.is_empty())
                .unwrap_or("")
                .to_string()
        })
        .unwrap_or_default()
}

/// Runs the whole pipeline of the module doc: lists and copies the photos, runs COLMAP's
/// three stages, picks the model with the most registered images and writes
/// `OUT/transforms.json` (atomically, last, so a failed run leaves none). One-line errors:
/// no photos, COLMAP missing, an earlier run's outputs in `OUT`, a stage that failed (naming
/// its log), fewer than [`MIN_REGISTERED`] images registered, a camera model nerfstudio
/// cannot hold.
pub fn process(options: &ProcessOptions) -> Result<ProcessSummary> {
    let ProcessOptions {
        images: source,
        out,
        matcher,
    } = options;
    let names = list_images(source, Some(out))?;
    let program = colmap_program();
    check_colmap(&program)?;
    let earlier = earlier_outputs(out);
    if !earlier.is_empty() {
        bail!(
            "{} already holds {} from an earlier run: remove them or choose another --out",
            out.display(),
            earlier.join(", ")
        );
    }
    let images = out.join("images");
    let colmap = out.join("colmap");
    let sparse = colmap.join("sparse");
    std::fs::create_dir_all(&sparse)
        .with_context(|| format!("cannot create {}", sparse.display()))?;
    log::info!(
        "{} photos in {}: copying them to {}",
        names.len(),
        source.display(),
        images.display()
    );
    copy_images(source, &names, &images)?;

    let database = colmap.join("database.db");
    let n = names.len();
    let matcher = matcher.command(n);
    let blocks = n.div_ceil(EXHAUSTIVE_BLOCK).pow(2);
    let mapper_inputs = mapper_inputs(&database, &images);
    let stages: [(&'static str, Vec<&std::ffi::OsStr>, usize); 3] = [
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
                "OPENCV".as_ref(),
                "--SiftExtraction.use_gpu".as_ref(),
                "0".as_ref(),
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
            ],
            if matcher == "exhaustive_matcher" {
                blocks
            } else {
                n
            },
        ),
        (
            "mapper",
            mapper_inputs
                .iter()
                .map(|a| a.as_os_str())
                .chain(["--output_path".as_ref(), sparse.as_os_str()])
                .chain(MAPPER_THRESHOLDS.iter().map(|a| a.as_ref()))
                .collect(),
            n,
        ),
    ];
    let mut times = Vec::new();
    for (stage, args, steps) in stages {
        let log = colmap.join(format!("{stage}.log"));
        let (status, seconds) = run_stage(&program, stage, &args, &log, steps as u64)?;
        let failed_to_map =
            stage == "mapper" && crate::io::colmap::find_model_folder(&colmap).is_none();
        if !status.success() && !failed_to_map {
            bail!(
                "COLMAP's {stage} failed ({status}): see {} (its last line: {})",
                log.display(),
                last_line(&log)
            );
        }
        log::info!("COLMAP {stage}: {seconds:.1} s (log: {})", log.display());
        times.push(StageTime { stage, seconds });
    }

    retry_mapper(&program, &colmap, &mapper_inputs, n)?;
    let mapper_log = colmap.join("mapper.log");
    let too_few = |registered: usize| {
        anyhow!(
            "COLMAP registered {registered} of {n} images; at least {MIN_REGISTERED} are needed: take photos with more overlap and texture (see {})",
            mapper_log.display()
        )
    };
    let (model_dir, model) = match crate::io::colmap::find_model_folder(&colmap) {
        Some(_) => crate::io::colmap::find_model(&colmap)?,
        None => return Err(too_few(0)),
    };
    let registered = model.images.len();
    if registered < MIN_REGISTERED {
        return Err(too_few(registered));
    }
    let transforms = transforms_json(&model)?;
    let text = serde_json::to_string_pretty(&transforms)? + "\n";
    let transforms_path = out.join("transforms.json");
    crate::io::output::write_text(&transforms_path, &text)?;
    let left_out = n - registered.min(n);
    log::info!(
        "COLMAP registered {registered} of {n} images (model {}){}",
        model_dir.display(),
        if left_out > 0 {
            format!("; the {left_out} it did not register are left out of transforms.json")
        } else {
            String::new()
        }
    );
    Ok(ProcessSummary {
        images: n,
        registered,
        model_dir,
        transforms: transforms_path,
        stages: times,
    })
}

/// The mapper's thresholds, below COLMAP's defaults (100, 30, 16°, 0.25): with them the 100
/// lego views (few features each) register 100 of 100 instead of 10.
const MAPPER_THRESHOLDS: [&str; 8] = [
    "--Mapper.init_min_num_inliers",
    "30",
    "--Mapper.abs_pose_min_num_inliers",
    "15",
    "--Mapper.init_min_tri_angle",
    "4",
    "--Mapper.abs_pose_min_inlier_ratio",
    "0.1",
];

/// The mapper's inputs: the database and the images.
fn mapper_inputs(database: &Path, images: &Path) -> Vec<std::ffi::OsString> {
    vec![
        "--database_path".into(),
        database.into(),
        "--image_path".into(),
        images.into(),
    ]
}

/// Images registered by the model COLMAP wrote under `dir` (0 when there is none).
fn registered_in(dir: &Path) -> usize {
    if crate::io::colmap::find_model_folder(dir).is_none() {
        return 0;
    }
    crate::io::colmap::find_model(dir).map_or(0, |(_, m)| m.images.len())
}

/// COLMAP's incremental mapper picks its initial pair by RANSAC on its own threads: on photos
/// with few features one run can end with no model where the next registers most of them.
/// While the model in `colmap/sparse` registers under half of the `n` photos, the mapper runs
/// again with another `--random_seed` (at most [`MAPPER_ATTEMPTS`] runs in all) into a folder
/// of its own, and the best model is kept as `colmap/sparse`. Each run's log is
/// `colmap/mapper_seed<k>.log`.
fn retry_mapper(
    program: &Path,
    colmap: &Path,
    inputs: &[std::ffi::OsString],
    n: usize,
) -> Result<()> {
    let sparse = colmap.join("sparse");
    let mut best = registered_in(&sparse);
    for seed in 1..MAPPER_ATTEMPTS {
        if 2 * best >= n {
            break;
        }
        log::info!(
            "COLMAP registered {best} of {n} images: running the mapper again (seed {seed})"
        );
        let attempt = colmap.join(format!("sparse_seed{seed}"));
        std::fs::create_dir_all(&attempt)
            .with_context(|| format!("cannot create {}", attempt.display()))?;
        let seed_text = seed.to_string();
        let mut args: Vec<&std::ffi::OsStr> = inputs.iter().map(|a| a.as_os_str()).collect();
        args.extend([std::ffi::OsStr::new("--output_path"), attempt.as_os_str()]);
        args.extend([
            std::ffi::OsStr::new("--random_seed"),
            std::ffi::OsStr::new(&seed_text),
        ]);
        args.extend(MAPPER_THRESHOLDS.iter().map(std::ffi::OsStr::new));
        let log = colmap.join(format!("mapper_seed{seed}.log"));
        run_stage(program, "mapper", &args, &log, n as u64)?;
        let registered = registered_in(&attempt);
        if registered > best {
            std::fs::remove_dir_all(&sparse)
                .with_context(|| format!("cannot remove {}", sparse.display()))?;
            std::fs::rename(&attempt, &sparse)
                .with_context(|| format!("cannot move {} into place", attempt.display()))?;
            best = registered;
        } else {
            std::fs::remove_dir_all(&attempt)
                .with_context(|| format!("cannot remove {}", attempt.display()))?;
        }
    }
    Ok(())
}

/// Nerfstudio's camera → world matrix (4×4, row by row, OpenGL camera axes: +x right, +y up,
/// +z backward) of COLMAP's world → camera `pose` (OpenCV axes): the inverse of the pose,
/// with the camera's y and z axes negated.
pub fn opengl_camera_to_world(pose: &ColmapPose) -> [[f64; 4]; 4] {
    let rotation = pose.rotation.transpose();
    let center = pose.center();
    let axes = [rotation.x_axis, -rotation.y_axis, -rotation.z_axis, center];
    let mut m = [[0.0; 4]; 4];
    for (j, column) in axes.iter().enumerate() {
        for (i, value) in column.to_array().into_iter().enumerate() {
            m[i][j] = value;
        }
    }
    m[3][3] = 1.0;
    m
}

/// nerfstudio's intrinsics keys for a COLMAP camera: `camera_model` OPENCV (from
/// SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, and FULL_OPENCV without its
/// rational terms) or OPENCV_FISHEYE, `fl_x fl_y cx cy w h` and the distortion. An error
/// naming the model when nerfstudio cannot hold it.
pub fn intrinsics_json(camera: &ColmapCamera) -> Result<Map<String, Value>> {
    let model = ColmapCameraModel::from_name(&camera.model)?;
    let (focal, principal, distortion) = model
        .intrinsics(&camera.params)
        .with_context(|| format!("COLMAP camera {}", camera.id))?;
    let mut keys = Map::new();
    let mut put = |k: &str, v: Value| {
        keys.insert(k.to_string(), v);
    };
    let name = match distortion {
        LensDistortion::Fisheye { .. } => "OPENCV_FISHEYE",
        _ => "OPENCV",
    };
    put("camera_model", json!(name));
    put("fl_x", json!(focal[0]));
    put("fl_y", json!(focal[1]));
    put("cx", json!(principal[0]));
    put("cy", json!(principal[1]));
    put("w", json!(camera.width));
    put("h", json!(camera.height));
    let (k, p) = match distortion {
        LensDistortion::None => ([0.0; 4], [0.0; 2]),
        LensDistortion::RadialTangential {
            numerator,
            denominator,
            tangential,
        } => {
            if denominator.iter().any(|&b| b != 0.0) {
                bail!(
                    "COLMAP camera {} is {} with rational terms k4..k6 {denominator:?}, which nerfstudio's OPENCV cannot hold",
                    camera.id,
                    camera.model
                );
            }
            (numerator, tangential)
        }
        LensDistortion::Fisheye { k } => (k, [0.0; 2]),
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
/// `file_path` `images/<name>` and `transform_matrix` ([`opengl_camera_to_world`]).
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
                json!(opengl_camera_to_world(&pose)),
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
    fn progress_lines() {
        assert_eq!(stage_progress("Processed file [3/24]"), Some((3, Some(24))));
        assert_eq!(
            stage_progress("Matching block [2/3, 1/3] in 4.5s"),
            Some((4, Some(9)))
        );
        assert_eq!(
            stage_progress("Matching image [7/120]"),
            Some((7, Some(120)))
        );
        assert_eq!(stage_progress("Registering image #18 (4)"), Some((4, None)));
        assert_eq!(
            stage_progress("Initializing with image pair #20 and #10"),
            Some((2, None))
        );
        assert_eq!(stage_progress("  Features:        1281"), None);
    }

    #[test]
    fn camera_to_world_round_trips() {
        let pose = ColmapPose::from_quaternion([0.9, 0.1, -0.3, 0.2], [0.5, -1.0, 2.0]).unwrap();
        let m = opengl_camera_to_world(&pose);
        let rows = [m[0], m[1], m[2]];
        let back = ColmapPose::from_opengl_camera_to_world(rows);
        assert!(back.rotation.abs_diff_eq(pose.rotation, 1e-12));
        assert!((back.translation - pose.translation).abs().max_element() < 1e-12);
        assert_eq!(m[3], [0.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn intrinsics_convert_or_refuse() {
        let camera = |model: &str, params: Vec<f64>| ColmapCamera {
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
    }
}
