//! `nerf report`: error against run time, measured on this machine and written as Markdown
//! with PNG plots.
//!
//! * **Box**: the box scene at `n_pts_per_ray` 8 … 1024, timed per frame, against the same
//!   scene at far more samples and, for a hard surface (β = 1e-4), against the analytic
//!   ray–box hit ([`crate::eval::reference::analytic_hit`]).
//! * **Lego**: a trained checkpoint at several sample counts with each acceleration the
//!   renderer offers, against the ground truth and against the dense render.
//! * **Training**: test PSNR against wall-clock time, from training logs.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use candle_core::Device;
use serde::Serialize;

use crate::app::bench::{machine_info, mean_psnr_of_views, MachineInfo};
use crate::app::config::Config;
use crate::core::camera::PerspectiveCamera;
use crate::core::metrics::psnr_from_mse;
use crate::core::metrics::{fastest, time_runs};
use crate::io::images::RgbImage;
use crate::io::plot::{write_line_plot, LinePlot, Series};
use crate::render::field::Field;
use crate::render::view::{render_view, RenderedView};

/// What `nerf report` measures and where it writes.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Directory for report.md, report.json and the plots.
    pub out_dir: PathBuf,
    /// CI-sized run: small images, fewer sample counts and views, one repeat.
    pub quick: bool,
    /// Trained NeRF for the lego section (skipped, with a note, when missing).
    pub checkpoint: PathBuf,
    /// Lego dataset (ground truth and test cameras).
    pub data_dir: PathBuf,
    /// Test views for the lego section (default 5, quick 2).
    pub views: Option<usize>,
    /// Training logs (`.log.jsonl`) to plot; missing ones are noted and skipped.
    pub training_logs: Vec<PathBuf>,
    /// A trained hash-grid field (the `lego_ngp` config's) for the lego section's hash-grid
    /// rows; none, or a missing file, leaves them out.
    pub ngp_checkpoint: Option<PathBuf>,
    /// Whether to measure the lego section. When true, a missing checkpoint or dataset is an
    /// error before anything is measured (see [`check_lego_inputs`]), not a silent omission.
    pub lego: bool,
}

/// An error naming what is missing when the lego section's checkpoint or dataset cannot be
/// read, with the working directory relative paths were taken from and how to go on.
pub fn check_lego_inputs(options: &ReportOptions) -> Result<()> {
    let cwd = std::env::current_dir()
        .map(|d| d.display().to_string())
        .unwrap_or_else(|_| "?".into());
    let relative = |p: &Path| {
        if p.is_relative() {
            format!(" (relative to the working directory {cwd})")
        } else {
            String::new()
        }
    };
    let to_go_on = "pass --checkpoint FILE and --data-dir DIR, or --no-lego to write the report \
                    without the lego section";
    if !options.checkpoint.is_file() {
        anyhow::bail!(
            "report: the lego section's checkpoint {} is not a file{}; {to_go_on}",
            options.checkpoint.display(),
            relative(&options.checkpoint)
        );
    }
    let transforms = options.data_dir.join("transforms_test.json");
    if !transforms.is_file() {
        anyhow::bail!(
            "report: the lego section's dataset {} has no transforms_test.json{}; {to_go_on}",
            options.data_dir.display(),
            relative(&options.data_dir)
        );
    }
    Ok(())
}

/// The 1-minute load average (`/proc/loadavg`), when the system tells it.
fn load_average() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next()?.parse().ok()
}

/// The name of the lego section's hash-grid rows.
pub const HASH_GRID_ROWS: &str = "hash grid (grid + early termination)";

/// The lego study's coarse-to-fine rows: the MLP rendered densely at `n/2` stratified depths
/// and `n/2` more drawn from their weights ([`crate::render::hierarchical`]).
pub const COARSE_TO_FINE_ROWS: &str = "coarse-to-fine (n/2 coarse + n/2 fine)";

/// Sizes of a full or a quick run.
#[derive(Debug, Clone, Serialize)]
pub struct Sizes {
    /// Width and height of the box renders, in pixels.
    pub box_size: usize,
    /// Sample counts (`n_pts_per_ray`) of the box study's rows.
    pub box_pts: Vec<usize>,
    /// Samples per ray of the box reference render.
    pub box_reference_pts: usize,
    /// Surround views rendered for the box study (indices, taken modulo the number of poses).
    pub box_views: Vec<usize>,
    /// Width and height of the lego renders, in pixels.
    pub lego_size: usize,
    /// Sample counts (`n_pts_per_ray`) of the lego study's rows.
    pub lego_pts: Vec<usize>,
    /// Samples per ray of the dense lego reference render.
    pub lego_reference_pts: usize,
    /// Lego test views rendered (at most the split's size).
    pub lego_views: usize,
    /// Timed renders per measurement (the fastest counts).
    pub repeats: usize,
}

impl Sizes {
    /// The full report's sizes, or the CI-sized ones with `quick`; `views` overrides the
    /// number of lego test views.
    pub fn new(quick: bool, views: Option<usize>) -> Self {
        if quick {
            Self {
                box_size: 64,
                box_pts: vec![8, 16, 32, 64, 128, 256],
                box_reference_pts: 2048,
                box_views: vec![0],
                lego_size: 64,
                lego_pts: vec![32, 128],
                lego_reference_pts: 128,
                lego_views: views.unwrap_or(2),
                repeats: 1,
            }
        } else {
            Self {
                box_size: 256,
                box_pts: (3..=10).map(|k| 1 << k).collect(),
                box_reference_pts: 8192,
                box_views: vec![0, 10],
                lego_size: 128,
                lego_pts: vec![32, 64, 128, 256],
                lego_reference_pts: 128,
                lego_views: views.unwrap_or(5),
                repeats: 2,
            }
        }
    }
}

/// Colour and depth error of a set of frames against reference values.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ImageError {
    /// Root-mean-square colour difference over all pixels and channels.
    pub color_rmse: f64,
    /// `−10·log10(MSE)` of the colour (images in [0, 1]).
    pub psnr: f64,
    /// Mean absolute depth difference over the pixels compared.
    pub depth_mae: f64,
    /// Pixels whose depth was compared.
    pub depth_pixels: usize,
}

/// Colour RMSE/PSNR over the pixels where `color_mask` is true, depth MAE over those where
/// `depth_mask` is true.
///
/// `colors`, `reference_colors`: `(P·3)`; `depths`, `reference_depths`, the masks: `(P)`.
pub fn image_error(
    colors: &[f32],
    reference_colors: &[f64],
    depths: &[f32],
    reference_depths: &[f64],
    color_mask: &[bool],
    depth_mask: &[bool],
) -> ImageError {
    let (sq, values) = colors
        .chunks_exact(3)
        .zip(reference_colors.chunks_exact(3))
        .zip(color_mask)
        .filter(|(_, m)| **m)
        .fold((0f64, 0usize), |(s, c), ((a, b), _)| {
            let d: f64 = a.iter().zip(b).map(|(a, b)| (*a as f64 - b).powi(2)).sum();
            (s + d, c + 3)
        });
    let mse = sq / values.max(1) as f64;
    let (sum, count) = depths
        .iter()
        .zip(reference_depths)
        .zip(depth_mask)
        .filter(|(_, m)| **m)
        .fold((0f64, 0usize), |(s, c), ((a, b), _)| {
            (s + (*a as f64 - b).abs(), c + 1)
        });
    ImageError {
        color_rmse: mse.sqrt(),
        psnr: psnr_from_mse(mse),
        depth_mae: if count > 0 {
            sum / count as f64
        } else {
            f64::NAN
        },
        depth_pixels: count,
    }
}

/// One sample count of a box study.
#[derive(Debug, Clone, Serialize)]
pub struct BoxRow {
    /// Samples per ray (`n_pts_per_ray`).
    pub n_pts: usize,
    /// Mean over the views of the fastest of the repeats.
    pub seconds_per_frame: f64,
    /// Against the same scene at `reference_pts` samples.
    pub vs_reference: ImageError,
    /// Against the analytic surface (hard box only): colour at the hit point (0 on a miss),
    /// depth on the pixels whose ray hits.
    pub vs_analytic: Option<ImageError>,
    /// The same without the grazing misses (within [`GRAZING_BETAS`]·β of the surface).
    pub vs_analytic_clear: Option<ImageError>,
    /// Grazing misses left out of `vs_analytic_clear`, over all views.
    pub grazing_pixels: usize,
}

/// The box scene at increasing sample counts.
#[derive(Debug, Clone, Serialize)]
pub struct BoxStudy {
    /// The volume's β.
    pub beta: f64,
    /// Samples per ray of the reference render.
    pub reference_pts: usize,
    /// One row per sample count, in increasing order.
    pub rows: Vec<BoxRow>,
}

/// The box config at one β, image size and sample count.
fn box_config(beta: f64, size: usize, n_pts: usize) -> Result<Config> {
    Config::load(
        "box",
        &[
            format!("implicit_function.beta.val={beta}"),
            format!("data.image_size=[{size},{size}]"),
            format!("sampler.n_pts_per_ray={n_pts}"),
        ],
    )
}

/// Renders `cameras` `repeats` times each; the frames of the last run and the mean over views
/// of each view's fastest time.
fn timed_frames(
    config: &Config,
    field: &dyn Field,
    cameras: &[PerspectiveCamera],
    repeats: usize,
    device: &Device,
) -> Result<(Vec<RenderedView>, f64)> {
    let (sampler, renderer) = (config.sampler()?, config.renderer()?);
    let mut frames = Vec::with_capacity(cameras.len());
    let mut total = 0.0;
    for camera in cameras {
        let (runs, frame) = time_runs(repeats, || {
            render_view(
                field,
                camera,
                config.image_size(),
                &sampler,
                &renderer,
                device,
            )
        })?;
        frames.push(frame);
        total += fastest(&runs);
    }
    Ok((frames, total / cameras.len().max(1) as f64))
}

/// Concatenated colours and depths of frames, as f64.
fn stacked(frames: &[RenderedView]) -> (Vec<f64>, Vec<f64>) {
    (
        frames
            .iter()
            .flat_map(|f| f.color.data.iter().map(|v| *v as f64))
            .collect(),
        frames
            .iter()
            .flat_map(|f| f.depth.iter().map(|v| *v as f64))
            .collect(),
    )
}

/// The analytic image of an SDF volume with a hard surface.
#[derive(Debug, Clone, Default)]
pub struct AnalyticImage {
    /// `(P·3)`: the colour at the first hit, 0 on a miss.
    pub colors: Vec<f64>,
    /// `(P)`: the hit distance, 0 on a miss.
    pub depths: Vec<f64>,
    /// `(P)`: whether the ray hits.
    pub hits: Vec<bool>,
    /// `(P)`: how close the ray comes to the surface within the sampled depths (0 on a hit).
    pub clearance: Vec<f64>,
}

impl AnalyticImage {
    fn extend(&mut self, other: AnalyticImage) {
        self.colors.extend(other.colors);
        self.depths.extend(other.depths);
        self.hits.extend(other.hits);
        self.clearance.extend(other.clearance);
    }
}

/// [`AnalyticImage`] of `volume` seen by `camera`, rays sampled up to `max_depth`.
pub fn analytic_image(
    volume: &crate::core::sdf::SdfVolume,
    camera: &PerspectiveCamera,
    (width, height): (usize, usize),
    max_depth: f64,
) -> AnalyticImage {
    let mut image = AnalyticImage::default();
    for [x, y] in crate::core::rays::pixel_grid_values(width, height) {
        let (o, d) = crate::core::rays::ray_through_ndc(camera, x, y);
        match crate::eval::reference::analytic_hit(&volume.sdf, o, d) {
            Some(t) => {
                image
                    .colors
                    .extend(crate::eval::reference::surface_color(volume, o + d * t));
                image.depths.push(t);
                image.hits.push(true);
                image.clearance.push(0.0);
            }
            None => {
                image.colors.extend([0.0; 3]);
                image.depths.push(0.0);
                image.hits.push(false);
                image
                    .clearance
                    .push(crate::eval::reference::closest_approach(
                        &volume.sdf,
                        o,
                        d,
                        max_depth,
                    ));
            }
        }
    }
    image
}

/// Misses that pass closer than this many β to the surface are "grazing": there a sample's
/// density is up to ½ whatever the spacing, so with the homework's σ = −ln(1 − density)/Δ
/// such rays turn opaque as samples are added instead of converging to a miss. At 20β the
/// density is below 1e-9.
pub const GRAZING_BETAS: f64 = 20.0;

/// The box at every sample count of `sizes`, against `sizes.box_reference_pts` samples and,
/// when `hard`, against the analytic surface.
pub fn box_study(
    beta: f64,
    hard: bool,
    sizes: &Sizes,
    device: &Device,
    progress: &crate::io::progress::Progress,
) -> Result<BoxStudy> {
    let size = sizes.box_size;
    let reference_config = box_config(beta, size, sizes.box_reference_pts)?;
    let field = reference_config.sdf_field(device)?;
    let volume = reference_config.sdf_volume()?;
    let all_cameras = reference_config.surround_cameras();
    let cameras: Vec<PerspectiveCamera> = sizes
        .box_views
        .iter()
        .map(|&v| all_cameras[v % all_cameras.len()])
        .collect();
    let (reference, _) = timed_frames(&reference_config, &field, &cameras, 1, device)?;
    progress.inc(1);
    let (ref_colors, ref_depths) = stacked(&reference);
    let all_pixels = vec![true; ref_depths.len()];
    let max_depth = reference_config.sampler.max_depth;
    let analytic = hard.then(|| {
        let mut image = AnalyticImage::default();
        for cam in &cameras {
            image.extend(analytic_image(&volume, cam, (size, size), max_depth));
        }
        let clear: Vec<bool> = image
            .clearance
            .iter()
            .map(|c| *c == 0.0 || *c > GRAZING_BETAS * beta)
            .collect();
        (image, clear)
    });
    let mut rows = Vec::new();
    for &n in &sizes.box_pts {
        let config = box_config(beta, size, n)?;
        let (frames, seconds) = timed_frames(&config, &field, &cameras, sizes.repeats, device)?;
        let (colors, depths): (Vec<f32>, Vec<f32>) = (
            frames.iter().flat_map(|f| f.color.data.clone()).collect(),
            frames.iter().flat_map(|f| f.depth.clone()).collect(),
        );
        rows.push(BoxRow {
            n_pts: n,
            seconds_per_frame: seconds,
            vs_reference: image_error(
                &colors,
                &ref_colors,
                &depths,
                &ref_depths,
                &all_pixels,
                &all_pixels,
            ),
            vs_analytic: analytic.as_ref().map(|(a, _)| {
                image_error(&colors, &a.colors, &depths, &a.depths, &all_pixels, &a.hits)
            }),
            vs_analytic_clear: analytic.as_ref().map(|(a, clear)| {
                image_error(&colors, &a.colors, &depths, &a.depths, clear, &a.hits)
            }),
            grazing_pixels: analytic
                .as_ref()
                .map_or(0, |(_, clear)| clear.iter().filter(|c| !**c).count()),
        });
        progress.inc(1);
    }
    Ok(BoxStudy {
        beta,
        reference_pts: sizes.box_reference_pts,
        rows,
    })
}

/// One sample count and acceleration of the lego study.
#[derive(Debug, Clone, Serialize)]
pub struct LegoRow {
    /// Name of the acceleration (see [`accelerations`]).
    pub acceleration: String,
    /// Samples per ray (`n_pts_per_ray`).
    pub n_pts: usize,
    /// Mean over the views of the fastest of the repeats.
    pub seconds_per_frame: f64,
    /// Mean PSNR against the test images.
    pub psnr_vs_truth: f64,
    /// Mean PSNR against the dense render at `reference_pts`.
    pub psnr_vs_dense: f64,
    /// Fraction of the samples at which the field was evaluated.
    pub evaluated: f64,
}

/// The trained NeRF at several sample counts and accelerations.
#[derive(Debug, Clone, Serialize)]
pub struct LegoStudy {
    /// The checkpoint rendered.
    pub checkpoint: PathBuf,
    /// Width and height of the renders, in pixels.
    pub size: usize,
    /// Test views rendered.
    pub views: usize,
    /// Samples per ray of the dense reference render.
    pub reference_pts: usize,
    /// One row per acceleration and sample count.
    pub rows: Vec<LegoRow>,
}

/// The accelerations the renderer offers, as overrides of the `lego` config (which has both
/// on): name and overrides.
pub fn accelerations() -> Vec<(&'static str, Vec<&'static str>)> {
    vec![
        (
            "dense",
            vec![
                "renderer.early_termination=0",
                "renderer.occupancy_grid=null",
            ],
        ),
        ("early termination", vec!["renderer.occupancy_grid=null"]),
        ("occupancy grid", vec!["renderer.early_termination=0"]),
        ("grid + early termination", vec![]),
    ]
}

/// The lego study, or why it was skipped.
pub fn lego_study(
    options: &ReportOptions,
    sizes: &Sizes,
    device: &Device,
    progress: &crate::io::progress::Progress,
) -> Result<LegoStudy> {
    crate::io::checkpoint_file::ensure_checkpoint_file(&options.checkpoint)?;
    let size = sizes.lego_size;
    let config_for = |n: usize, extra: &[&str]| -> Result<Config> {
        let mut overrides = vec![
            format!("data.image_size=[{size},{size}]"),
            format!("sampler.n_pts_per_ray={n}"),
        ];
        overrides.extend(extra.iter().map(|s| s.to_string()));
        Config::load("lego", &overrides)
    };
    let base = config_for(sizes.lego_reference_pts, &[])?;
    let dataset = crate::io::dataset::Dataset::load(
        &options.data_dir,
        crate::io::dataset::Split::Test,
        size,
        size,
        base.renderer.white_background,
    )
    .with_context(|| format!("lego dataset at {}", options.data_dir.display()))?;
    let views = sizes.lego_views.min(dataset.frames.len());
    let cameras: Vec<PerspectiveCamera> = dataset
        .frames
        .iter()
        .take(views)
        .map(|f| f.camera)
        .collect();
    let truth: Vec<RgbImage> = dataset.images.iter().take(views).cloned().collect();
    let run = |config: &Config| -> Result<(Vec<RenderedView>, f64)> {
        let (state, _) = config.load_model(&options.checkpoint, device)?;
        timed_frames(
            config,
            &*state.render_field(),
            &cameras,
            sizes.repeats,
            device,
        )
    };
    let dense_overrides = &accelerations()[0].1;
    let (reference, _) = run(&config_for(sizes.lego_reference_pts, dense_overrides)?)?;
    let reference: Vec<RgbImage> = reference.into_iter().map(|f| f.color).collect();
    progress.inc(1);
    let scored = |name: &str, n, seconds, frames: &[RenderedView]| {
        lego_row(name, n, seconds, frames, &truth, Some(&reference))
    };
    let mut rows = Vec::new();
    for (name, overrides) in accelerations() {
        for &n in &sizes.lego_pts {
            let (frames, seconds) = run(&config_for(n, &overrides)?)?;
            rows.push(scored(name, n, seconds, &frames));
            progress.inc(1);
        }
    }
    for &n in &sizes.lego_pts {
        let half = (n / 2).max(1);
        let fine = format!("sampler.n_pts_per_ray_fine={}", n - half);
        let mut overrides: Vec<&str> = dense_overrides.iter().map(|s| s.as_ref()).collect();
        overrides.push(&fine);
        let (frames, seconds) = run(&config_for(half, &overrides)?)?;
        rows.push(scored(COARSE_TO_FINE_ROWS, n, seconds, &frames));
        progress.inc(1);
    }
    if let Some(ngp) = options.ngp_checkpoint.as_ref().filter(|p| p.is_file()) {
        rows.extend(hash_grid_rows(ngp, sizes, &cameras, &truth, device)?);
    }
    Ok(LegoStudy {
        checkpoint: options.checkpoint.clone(),
        size,
        views,
        reference_pts: sizes.lego_reference_pts,
        rows,
    })
}

/// The lego study's hash-grid rows: the checkpoint `ngp` with the `lego_ngp` config at each
/// of the study's sample counts, on `cameras`, scored against `truth`.
fn hash_grid_rows(
    ngp: &Path,
    sizes: &Sizes,
    cameras: &[PerspectiveCamera],
    truth: &[RgbImage],
    device: &Device,
) -> Result<Vec<LegoRow>> {
    let size = sizes.lego_size;
    let mut rows = Vec::new();
    for &n in &sizes.lego_pts {
        let config = Config::load(
            "lego_ngp",
            &[
                format!("data.image_size=[{size},{size}]"),
                format!("sampler.n_pts_per_ray={n}"),
                format!("training.checkpoint_path={}", ngp.display()),
            ],
        )?;
        let field = config.load_field(ngp, device)?;
        let (frames, seconds) = timed_frames(&config, &*field, cameras, sizes.repeats, device)?;
        rows.push(lego_row(HASH_GRID_ROWS, n, seconds, &frames, truth, None));
    }
    Ok(rows)
}

/// A lego study row of `frames` rendered in `seconds` per frame with `n_pts` samples per
/// ray, scored against `truth` and against the dense `reference` frames (without one,
/// `psnr_vs_dense` is NaN).
fn lego_row(
    acceleration: &str,
    n_pts: usize,
    seconds: f64,
    frames: &[RenderedView],
    truth: &[RgbImage],
    reference: Option<&[RgbImage]>,
) -> LegoRow {
    let counts = frames
        .iter()
        .fold(crate::render::skipping::SampleCounts::default(), |a, f| {
            a + f.samples
        });
    LegoRow {
        acceleration: acceleration.to_string(),
        n_pts,
        seconds_per_frame: seconds,
        psnr_vs_truth: mean_psnr_of_views(frames, truth),
        psnr_vs_dense: reference.map_or(f64::NAN, |r| mean_psnr_of_views(frames, r)),
        evaluated: counts.evaluated_fraction(),
    }
}

/// Test PSNR and per-epoch training PSNR of one training log against its wall clock.
#[derive(Debug, Clone, Serialize)]
pub struct TrainingCurve {
    /// The training log read.
    pub log: PathBuf,
    /// `(wall seconds, epoch, test PSNR)` at each evaluation.
    pub test: Vec<(f64, usize, f64)>,
    /// Test views of each evaluation.
    pub test_views: Option<usize>,
    /// `(wall seconds at the epoch's last step, epoch, mean training-batch PSNR)`.
    pub train: Vec<(f64, usize, f64)>,
}

/// The largest training log a report reads (a 45-minute run logs about 2 MB).
const MAX_LOG_BYTES: u64 = 256 << 20;

/// Reads a training log (`.log.jsonl`, one JSON object per line: steps with `psnr`,
/// evaluations with `test_psnr`).
pub fn read_training_log(path: &Path) -> Result<TrainingCurve> {
    // A regular file of bounded size: a FIFO or /dev/zero given as --log is refused, not read
    // forever.
    let bytes = crate::io::bounded_read::read_regular_file(path, "training log", MAX_LOG_BYTES)?;
    let text = String::from_utf8(bytes)
        .map_err(|_| anyhow::anyhow!("training log {} is not UTF-8 text", path.display()))?;
    let mut test = Vec::new();
    let mut test_views = None;
    // epoch -> (last wall_s, psnr sum, count)
    let mut epochs: std::collections::BTreeMap<usize, (f64, f64, usize)> = Default::default();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("{} line {}: not JSON", path.display(), i + 1))?;
        let num = |k: &str| v.get(k).and_then(|x| x.as_f64());
        let (Some(wall), Some(epoch)) = (num("wall_s"), num("epoch")) else {
            bail!("{} line {}: no wall_s or epoch", path.display(), i + 1);
        };
        if let Some(p) = num("test_psnr") {
            test.push((wall, epoch as usize, p));
            test_views = num("test_views").map(|n| n as usize).or(test_views);
        } else if let Some(p) = num("psnr") {
            let e = epochs.entry(epoch as usize).or_insert((0.0, 0.0, 0));
            *e = (e.0.max(wall), e.1 + p, e.2 + 1);
        }
    }
    let train: Vec<_> = epochs
        .into_iter()
        .map(|(epoch, (wall, sum, n))| (wall, epoch, sum / n as f64))
        .collect();
    if train.is_empty() && test.is_empty() {
        bail!("{}: no training steps logged", path.display());
    }
    Ok(TrainingCurve {
        log: path.to_path_buf(),
        test,
        test_views,
        train,
    })
}

/// Everything a report holds (also written as report.json).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The machine the report was measured on.
    pub machine: MachineInfo,
    /// Whether this is the CI-sized run.
    pub quick: bool,
    /// The sizes measured.
    pub sizes: Sizes,
    /// Wall-clock seconds the whole measurement took.
    pub seconds: f64,
    /// The system's 1-minute load average before and after the measurement (`None` where
    /// the system does not tell it): how busy the machine was, which the report can only
    /// state, not control.
    pub load_average: [Option<f64>; 2],
    /// The homework's box (β = [`HOMEWORK_BETA`]) against many samples.
    pub homework_box: BoxStudy,
    /// The hard box (β = [`HARD_BETA`]) against many samples and the analytic surface.
    pub hard_box: BoxStudy,
    /// The lego study, or why it was skipped.
    pub lego: std::result::Result<LegoStudy, String>,
    /// One training curve per log, or why the log could not be read.
    pub training: Vec<std::result::Result<TrainingCurve, String>>,
}

/// β of the homework's box.
pub const HOMEWORK_BETA: f64 = 0.05;
/// β of the hard box, whose surface is sharp enough to compare with the analytic hit.
pub const HARD_BETA: f64 = 1e-4;

/// The training logs a report plots by default: the checkpoint's `.log.jsonl` and the
/// homework-trained model's.
pub fn default_training_logs(checkpoint: &Path) -> Vec<PathBuf> {
    vec![
        checkpoint.with_extension("log.jsonl"),
        PathBuf::from("checkpoints/homework/nerf_lego.log.jsonl"),
        PathBuf::from(crate::app::runtime::SHIPPED_NGP_CHECKPOINT).with_extension("log.jsonl"),
    ]
}

/// Runs every measurement.
pub fn measure(options: &ReportOptions, device: &Device) -> Result<Report> {
    let start = Instant::now();
    let load_before = load_average();
    let sizes = Sizes::new(options.quick, options.views);
    let box_renders = 2 * (1 + sizes.box_pts.len());
    let lego_renders = 1 + (accelerations().len() + 1) * sizes.lego_pts.len();
    let progress = crate::io::progress::progress_bar((box_renders + lego_renders) as u64, "report");
    let homework_box = box_study(HOMEWORK_BETA, false, &sizes, device, &progress)?;
    let hard_box = box_study(HARD_BETA, true, &sizes, device, &progress)?;
    let lego = if options.lego {
        lego_study(options, &sizes, device, &progress).map_err(|e| format!("{e:#}"))
    } else {
        Err("left out (--no-lego)".to_string())
    };
    progress.finish_and_clear();
    let training = options
        .training_logs
        .iter()
        .map(|p| read_training_log(p).map_err(|e| format!("{e:#}")))
        .collect();
    Ok(Report {
        machine: machine_info(),
        quick: options.quick,
        sizes,
        seconds: start.elapsed().as_secs_f64(),
        load_average: [load_before, load_average()],
        homework_box,
        hard_box,
        lego,
        training,
    })
}

fn machine_line(m: &MachineInfo) -> String {
    format!(
        "Machine: {}, {} threads, {} build.",
        m.cpu, m.threads, m.profile
    )
}

fn box_plot(report: &Report) -> LinePlot {
    let series = |label: &str, study: &BoxStudy, pick: &dyn Fn(&BoxRow) -> Option<f64>| Series {
        label: label.to_string(),
        points: study
            .rows
            .iter()
            .filter_map(|r| pick(r).map(|e| (r.seconds_per_frame, e)))
            .collect(),
    };
    LinePlot {
        title: format!(
            "Box, {0}x{0}: error against time per frame (8 to {1} samples per ray)",
            report.sizes.box_size,
            report.sizes.box_pts.last().copied().unwrap_or(0)
        ),
        x_label: "seconds per frame".into(),
        y_label: "error".into(),
        log_x: true,
        log_y: true,
        legend: plotters::prelude::SeriesLabelPosition::LowerLeft,
        series: vec![
            series(
                "hard box: mean |depth - analytic hit|",
                &report.hard_box,
                &|r| r.vs_analytic.map(|e| e.depth_mae),
            ),
            series(
                "hard box: colour RMSE vs analytic (grazing misses left out)",
                &report.hard_box,
                &|r| r.vs_analytic_clear.map(|e| e.color_rmse),
            ),
            series(
                "hard box: colour RMSE vs analytic, all pixels",
                &report.hard_box,
                &|r| r.vs_analytic.map(|e| e.color_rmse),
            ),
            series(
                "homework box: colour RMSE vs most samples",
                &report.homework_box,
                &|r| Some(r.vs_reference.color_rmse),
            ),
            series(
                "homework box: mean |depth| diff vs most samples",
                &report.homework_box,
                &|r| Some(r.vs_reference.depth_mae),
            ),
        ]
        .into_iter()
        .map(|mut s| {
            // A log axis cannot show an exact zero (the reference row itself).
            s.points.retain(|p| p.1 > 0.0);
            s
        })
        .collect(),
    }
}

fn lego_plot(study: &LegoStudy) -> LinePlot {
    LinePlot {
        title: format!(
            "Lego, {0}x{0}: PSNR against time per frame (samples per ray {1})",
            study.size,
            study
                .rows
                .iter()
                .map(|r| r.n_pts)
                .collect::<std::collections::BTreeSet<_>>()
                .iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        x_label: "seconds per frame".into(),
        y_label: "PSNR vs ground truth (dB)".into(),
        log_x: true,
        log_y: false,
        legend: plotters::prelude::SeriesLabelPosition::LowerRight,
        series: accelerations()
            .iter()
            .map(|(name, _)| *name)
            .chain([COARSE_TO_FINE_ROWS, HASH_GRID_ROWS])
            .filter(|name| study.rows.iter().any(|r| r.acceleration == *name))
            .map(|name| Series {
                label: name.to_string(),
                points: study
                    .rows
                    .iter()
                    .filter(|r| r.acceleration == name)
                    .map(|r| (r.seconds_per_frame, r.psnr_vs_truth))
                    .collect(),
            })
            .collect(),
    }
}

fn training_plot(curves: &[&TrainingCurve]) -> LinePlot {
    let mut series = Vec::new();
    for c in curves {
        // The log's path without `.log.jsonl`: the run it belongs to.
        let path = c.log.display().to_string();
        let name = path.strip_suffix(".log.jsonl").unwrap_or(&path);
        if !c.test.is_empty() {
            series.push(Series {
                label: format!(
                    "{name}: test PSNR ({} views)",
                    c.test_views.map_or("?".into(), |n| n.to_string())
                ),
                points: c.test.iter().map(|(w, _, p)| (w / 60.0, *p)).collect(),
            });
        }
        series.push(Series {
            label: format!("{name}: training-batch PSNR (epoch mean)"),
            points: c.train.iter().map(|(w, _, p)| (w / 60.0, *p)).collect(),
        });
    }
    LinePlot {
        title: "Training: PSNR against wall-clock time".into(),
        x_label: "minutes of training".into(),
        y_label: "PSNR (dB)".into(),
        log_x: false,
        log_y: false,
        legend: plotters::prelude::SeriesLabelPosition::LowerRight,
        series,
    }
}

fn fmt_db(v: f64) -> String {
    if v.is_infinite() {
        "exact".into()
    } else if v.is_nan() {
        "—".into()
    } else {
        format!("{v:.2}")
    }
}

fn box_table(out: &mut String, study: &BoxStudy, analytic: bool) {
    if analytic {
        out.push_str("| samples per ray | seconds per frame | colour RMSE vs analytic, all pixels | colour RMSE vs analytic, grazing misses left out | PSNR of the same (dB) | mean abs. depth error vs analytic hit | colour RMSE vs most samples | mean abs. depth diff vs most samples |\n|---|---|---|---|---|---|---|---|\n");
    } else {
        out.push_str("| samples per ray | seconds per frame | colour RMSE vs most samples | PSNR vs most samples (dB) | mean abs. depth diff vs most samples |\n|---|---|---|---|---|\n");
    }
    for r in &study.rows {
        let e = &r.vs_reference;
        match (&r.vs_analytic, &r.vs_analytic_clear, analytic) {
            (Some(a), Some(c), true) => {
                let _ = writeln!(
                    out,
                    "| {} | {:.4} | {:.2e} | {:.2e} | {} | {:.2e} | {:.2e} | {:.2e} |",
                    r.n_pts,
                    r.seconds_per_frame,
                    a.color_rmse,
                    c.color_rmse,
                    fmt_db(c.psnr),
                    a.depth_mae,
                    e.color_rmse,
                    e.depth_mae
                );
            }
            _ => {
                let _ = writeln!(
                    out,
                    "| {} | {:.4} | {:.2e} | {} | {:.2e} |",
                    r.n_pts,
                    r.seconds_per_frame,
                    e.color_rmse,
                    fmt_db(e.psnr),
                    e.depth_mae
                );
            }
        }
    }
}

/// Least-squares slope of `log(error)` against `log(n)`: the observed convergence order.
pub fn log_log_slope(points: &[(f64, f64)]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Wall-clock minutes at which a curve first reaches each PSNR.
fn minutes_to_reach(points: &[(f64, usize, f64)], target: f64) -> Option<(f64, usize)> {
    points
        .iter()
        .find(|(_, _, p)| *p >= target)
        .map(|(w, e, _)| (w / 60.0, *e))
}

/// The report as Markdown, plots referenced by file name.
pub fn markdown(report: &Report, plots: &[(String, String)]) -> String {
    let mut out = String::new();
    let m = machine_line(&report.machine);
    let _ = writeln!(
        out,
        "# nerf report: error against run time\n\nMade by `nerf report{}` in {:.0} s. {m} \
         Times are wall-clock seconds on this machine; {} Errors are measured, not \
         estimated.\n",
        if report.quick { " --quick" } else { "" },
        report.seconds,
        load_sentence(report.load_average, report.machine.threads)
    );
    let plot = |name: &str| plot_link(plots, name);

    box_section(&mut out, report, &plot("box"), &m);
    lego_section(&mut out, report, &plot("lego"), &m);
    training_section(&mut out, report, &plot("training"));
    out
}

/// What the load average says of the timings: other work on the machine slows them, and the
/// report cannot know of it otherwise.
fn load_sentence(load: [Option<f64>; 2], threads: usize) -> String {
    match load {
        [Some(before), Some(after)] => format!(
            "the 1-minute load average was {before:.2} before the run and {after:.2} after it \
             (the run's own {threads} threads count towards the second; a first figure well \
             above 0 means other work shared the cores)."
        ),
        _ => "the load on the machine during the run is unknown (no /proc/loadavg).".into(),
    }
}

/// A Markdown image link to the plot named `name`, or nothing when it was not drawn.
fn plot_link(plots: &[(String, String)], name: &str) -> String {
    plots
        .iter()
        .find(|(n, _)| n == name)
        .map(|(n, f)| format!("![{n}]({f})\n\n"))
        .unwrap_or_default()
}

/// The box section: hard box against the analytic hit, homework box against many samples.
fn box_section(out: &mut String, report: &Report, plot: &str, m: &str) {
    let s = &report.sizes;
    let _ = writeln!(
        out,
        "## Box: samples per ray against error\n\n{m} Image {0}x{0}, view(s) {1:?} of the 20 \
         surround views, fastest of {2} run(s) per frame. Deterministic stratified depths on \
         [0, 5] (the homework's), the last sample's delta 1e10.\n",
        s.box_size, s.box_views, s.repeats
    );
    out.push_str(plot);
    let hard_depth: Vec<(f64, f64)> = report
        .hard_box
        .rows
        .iter()
        .filter_map(|r| r.vs_analytic.map(|a| (r.n_pts as f64, a.depth_mae)))
        .collect();
    let hard_color: Vec<(f64, f64)> = report
        .hard_box
        .rows
        .iter()
        .filter_map(|r| r.vs_analytic_clear.map(|a| (r.n_pts as f64, a.color_rmse)))
        .collect();
    let grazing = report.hard_box.rows.first().map_or(0, |r| r.grazing_pixels);
    let pixels = s.box_size * s.box_size * s.box_views.len();
    let slope = |p: &[(f64, f64)]| log_log_slope(p).map_or("-".into(), |v| format!("{v:.2}"));
    let _ = writeln!(
        out,
        "### Hard box (β = {}), against the analytic ray–box hit\n\nWith β this small the \
         surface is a step: a sample's density is 0 outside and 1 (σ = ∞, opaque) inside, so \
         the render converges to the analytic surface. Colour is compared over all pixels \
         (a miss is black), depth over the pixels whose ray hits the box (a ray that only grazes an \
         edge crosses no volume and counts as a miss). The depth error falls as n^{} and the \
         colour error, grazing misses left out, as n^{} (least-squares slopes over the table; \
         the sample spacing is 5/n).\n\n\
         Grazing misses are rays that pass within {}β of the surface without entering it \
         ({grazing} of the {pixels} pixels here). Every sample there has a density near ½, and \
         the homework's σ = −ln(1 − density)/Δ gives each sample that opacity whatever the \
         spacing, so these rays turn opaque as samples are added instead of converging to a \
         miss: the colour error over all pixels stops falling at high sample counts because of \
         them.{} The last two columns compare with {} samples per ray.\n",
        report.hard_box.beta,
        slope(&hard_depth),
        slope(&hard_color),
        GRAZING_BETAS,
        if s.box_size == 256 {
            " (At 256×256 the box's silhouette edges, at NDC ±7/17, fall exactly on pixel \
             rows and columns: 1 − 2·75/255 = 7/17.)"
        } else {
            ""
        },
        report.hard_box.reference_pts
    );
    box_table(out, &report.hard_box, true);
    let _ = writeln!(
        out,
        "\n### Homework box (β = {}), against {} samples per ray\n\nThe homework's \
         density → σ rule, σ = −ln(1 − density)/Δ, makes each sample's opacity \
         1 − exp(−σΔ) equal to its density whatever the spacing Δ. More samples therefore \
         means more opacity in front of the surface, not a finer estimate of the same \
         integral: the image has no limit as n grows (the soft shell outside the surface keeps \
         getting more opaque). \
         The columns below are differences to the {1}-sample render, which only show how \
         far each sample count is from that one; they do not shrink to a converged answer.\n",
        report.homework_box.beta, report.homework_box.reference_pts
    );
    box_table(out, &report.homework_box, false);
    out.push('\n');
}

/// The lego section: accelerations and samples per ray.
fn lego_section(out: &mut String, report: &Report, plot: &str, m: &str) {
    let s = &report.sizes;
    out.push_str("## Lego: accelerations and samples per ray\n\n");
    match &report.lego {
        Ok(l) => {
            let _ = writeln!(
                out,
                "{m} Checkpoint `{0}`, {1}x{1}, the first {2} test view(s), fastest of {3} \
                 run(s) per frame. PSNR against the ground truth (on black) and against the \
                 dense render at {4} samples per ray (the trained count). The occupancy grid \
                 is part of the shipped model (it was trained with it), so the dense render \
                 shows ghost density the grid removes and scores lower against the ground \
                 truth.\n",
                l.checkpoint.display(),
                l.size,
                l.views,
                s.repeats,
                l.reference_pts
            );
            if l.rows.iter().any(|r| r.acceleration == COARSE_TO_FINE_ROWS) {
                let _ = writeln!(
                    out,
                    "The `{COARSE_TO_FINE_ROWS}` rows render the same MLP densely in two \
                     passes (`sampler.n_pts_per_ray_fine`, pytorch3d's NeRF project's \
                     hierarchical sampling with one network): n/2 stratified samples, then \
                     n/2 more drawn from their weights, the fine pass evaluating all n. \
                     The field is evaluated at 150% of the n samples a ray keeps; compare \
                     the rows at equal seconds per frame.\n"
                );
            }
            if l.rows.iter().any(|r| r.acceleration == HASH_GRID_ROWS) {
                let _ = writeln!(
                    out,
                    "The `{HASH_GRID_ROWS}` rows render the hash-grid model `{}` (config \
                     `lego_ngp`) on the same views; it has no dense reference.\n",
                    crate::app::runtime::SHIPPED_NGP_CHECKPOINT
                );
            }
            out.push_str(plot);
            out.push_str("| acceleration | samples per ray | seconds per frame | PSNR vs ground truth (dB) | PSNR vs dense render (dB) | field evaluated at |\n|---|---|---|---|---|---|\n");
            for r in &l.rows {
                let _ = writeln!(
                    out,
                    "| {} | {} | {:.3} | {:.2} | {} | {:.1}% |",
                    r.acceleration,
                    r.n_pts,
                    r.seconds_per_frame,
                    r.psnr_vs_truth,
                    fmt_db(r.psnr_vs_dense),
                    100.0 * r.evaluated
                );
            }
            out.push('\n');
        }
        Err(e) => {
            let _ = writeln!(out, "Skipped: {e}.\n");
        }
    }
}

/// The training section: PSNR against wall-clock time from the logs.
fn training_section(out: &mut String, report: &Report, plot: &str) {
    out.push_str("## Training: PSNR against wall-clock time\n\n");
    let curves: Vec<&TrainingCurve> = report
        .training
        .iter()
        .filter_map(|c| c.as_ref().ok())
        .collect();
    if !curves.is_empty() {
        out.push_str(
            "From the training logs: wall-clock seconds as the run logged them (evaluation \
             excluded), on the machine that trained the model (the 2-core development \
             machine, release build). Test PSNR is logged only by runs with \
             `training.eval_views`.\n\n",
        );
        out.push_str(plot);
        out.push_str("| log | epochs | minutes | last test PSNR (dB) | minutes to 20 / 22 / 24 / 25 / 26 / 27 dB test PSNR | last training-batch PSNR (dB) |\n|---|---|---|---|---|---|\n");
        for c in &curves {
            let last_epoch = c.train.last().map_or(0, |t| t.1 + 1);
            let minutes = c
                .train
                .last()
                .map(|t| t.0)
                .into_iter()
                .chain(c.test.last().map(|t| t.0))
                .fold(0.0, f64::max)
                / 60.0;
            let reach = [20.0, 22.0, 24.0, 25.0, 26.0, 27.0]
                .iter()
                .map(|t| {
                    minutes_to_reach(&c.test, *t).map_or("-".into(), |(m, _)| format!("{m:.1}"))
                })
                .collect::<Vec<_>>()
                .join(" / ");
            let _ = writeln!(
                out,
                "| `{}` | {} | {:.1} | {} | {} | {} |",
                c.log.display(),
                last_epoch,
                minutes,
                c.test
                    .last()
                    .map_or("-".into(), |t| format!("{:.2} (epoch {})", t.2, t.1)),
                if c.test.is_empty() { "-".into() } else { reach },
                c.train.last().map_or("-".into(), |t| format!("{:.2}", t.2)),
            );
        }
        out.push('\n');
    }
    for e in report.training.iter().filter_map(|c| c.as_ref().err()) {
        let _ = writeln!(out, "Skipped a training log: {e}.\n");
    }
}

/// Measures, then writes `report.md`, `report.json` and the plots into `options.out_dir`.
/// Returns the paths written.
pub fn write_report(options: &ReportOptions, device: &Device) -> Result<Vec<PathBuf>> {
    if options.lego {
        check_lego_inputs(options)?;
    }
    std::fs::create_dir_all(&options.out_dir)
        .with_context(|| format!("creating {}", options.out_dir.display()))?;
    crate::io::output::remove_stale_temp_files(&options.out_dir);
    let report = measure(options, device)?;
    let mut written = Vec::new();
    let mut plots = Vec::new();
    let mut add_plot = |name: &str, file: &str, plot: LinePlot| -> Result<()> {
        let path = options.out_dir.join(file);
        write_line_plot(&path, &plot)?;
        written.push(path);
        plots.push((name.to_string(), file.to_string()));
        Ok(())
    };
    add_plot("box", "box_error_vs_time.png", box_plot(&report))?;
    if let Ok(l) = &report.lego {
        add_plot("lego", "lego_psnr_vs_time.png", lego_plot(l))?;
    }
    let curves: Vec<&TrainingCurve> = report
        .training
        .iter()
        .filter_map(|c| c.as_ref().ok())
        .collect();
    if !curves.is_empty() {
        add_plot(
            "training",
            "training_psnr_vs_time.png",
            training_plot(&curves),
        )?;
    }
    let md = options.out_dir.join("report.md");
    crate::io::output::write_text(&md, &markdown(&report, &plots))?;
    written.push(md);
    let json = options.out_dir.join("report.json");
    crate::io::output::write_text(&json, &serde_json::to_string_pretty(&report)?)?;
    written.push(json);
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_error_matches_hand_computed_values() {
        let e = image_error(
            &[0.5, 0.5, 0.5, 0.0, 0.0, 0.0],
            &[0.4, 0.5, 0.5, 0.0, 0.0, 0.3],
            &[3.0, 0.0],
            &[2.5, 9.0],
            &[true, true],
            &[true, false],
        );
        let mse: f64 = (0.1f64.powi(2) + 0.3f64.powi(2)) / 6.0;
        assert!((e.color_rmse - mse.sqrt()).abs() < 1e-7);
        assert!((e.psnr + 10.0 * mse.log10()).abs() < 1e-5);
        assert!((e.depth_mae - 0.5).abs() < 1e-12);
        assert_eq!(e.depth_pixels, 1);
        let none = image_error(&[0.0; 3], &[0.0; 3], &[1.0], &[2.0], &[true], &[false]);
        assert!(none.depth_mae.is_nan() && none.psnr.is_infinite());
        // The colour mask leaves out the second pixel.
        let first = image_error(
            &[0.5, 0.5, 0.5, 0.0, 0.0, 0.0],
            &[0.4, 0.5, 0.5, 0.0, 0.0, 0.3],
            &[3.0, 0.0],
            &[2.5, 9.0],
            &[true, false],
            &[true, false],
        );
        assert!((first.color_rmse - (0.01f64 / 3.0).sqrt()).abs() < 1e-7);
    }

    #[test]
    fn log_log_slope_recovers_a_power_law() {
        let pts: Vec<(f64, f64)> = [8.0, 16.0, 64.0, 1024.0]
            .iter()
            .map(|n: &f64| (*n, 3.0 * n.powf(-1.5)))
            .collect();
        assert!((log_log_slope(&pts).unwrap() + 1.5).abs() < 1e-12);
        assert!(log_log_slope(&pts[..1]).is_none());
    }

    #[test]
    fn a_training_log_that_is_no_regular_file_is_refused_without_reading() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("run.log.jsonl");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let err = format!("{:#}", read_training_log(&fifo).unwrap_err());
        assert!(
            err.contains("FIFO") && err.contains("training log"),
            "{err}"
        );
        let err = format!(
            "{:#}",
            read_training_log(Path::new("/dev/zero")).unwrap_err()
        );
        assert!(err.contains("device"), "{err}");
    }

    #[test]
    fn training_log_groups_steps_by_epoch_and_keeps_evaluations() {
        let dir = std::env::temp_dir().join(format!("nerf-report-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x.log.jsonl");
        std::fs::write(
            &path,
            concat!(
                "{\"step\":1,\"epoch\":0,\"wall_s\":1.0,\"loss\":0.1,\"psnr\":10.0}\n",
                "{\"step\":2,\"epoch\":0,\"wall_s\":2.0,\"loss\":0.1,\"psnr\":12.0}\n",
                "{\"step\":2,\"epoch\":1,\"wall_s\":2.5,\"test_psnr\":15.5,\"test_views\":20}\n",
                "\n",
                "{\"step\":3,\"epoch\":1,\"wall_s\":3.0,\"loss\":0.1,\"psnr\":14.0}\n",
            ),
        )
        .unwrap();
        let c = read_training_log(&path).unwrap();
        assert_eq!(c.train, vec![(2.0, 0, 11.0), (3.0, 1, 14.0)]);
        assert_eq!(c.test, vec![(2.5, 1, 15.5)]);
        assert_eq!(c.test_views, Some(20));
        assert_eq!(minutes_to_reach(&c.test, 15.0), Some((2.5 / 60.0, 1)));
        assert_eq!(minutes_to_reach(&c.test, 16.0), None);
        std::fs::write(&path, "{\"step\":1}\nnot json\n").unwrap();
        let err = read_training_log(&path).unwrap_err().to_string();
        assert!(err.contains("line 1"), "{err}");
        // An empty log is an error (the report notes it and leaves the plot out).
        std::fs::write(&path, "\n").unwrap();
        let err = read_training_log(&path).unwrap_err().to_string();
        assert!(err.contains("no training steps"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn hard_box_render_approaches_the_analytic_surface() {
        // 32×32, one view: the depth error against the analytic hit shrinks with the spacing.
        let sizes = Sizes {
            box_size: 32,
            box_pts: vec![16, 256],
            box_reference_pts: 512,
            box_views: vec![3],
            ..Sizes::new(true, None)
        };
        let bar = crate::io::progress::Progress::hidden();
        let study = box_study(HARD_BETA, true, &sizes, &Device::Cpu, &bar).unwrap();
        let errs: Vec<ImageError> = study.rows.iter().map(|r| r.vs_analytic.unwrap()).collect();
        assert!(
            errs[0].depth_pixels > 100,
            "the box covers part of the image"
        );
        // Spacing 5/16 = 0.31 and 5/256 = 0.02: at 256 samples the mean error is below one
        // spacing, and far below the error at 16 (where thin parts are missed altogether).
        assert!(errs[1].depth_mae < 5.0 / 256.0, "{}", errs[1].depth_mae);
        assert!(errs[1].depth_mae < errs[0].depth_mae / 8.0);
        assert!(errs[1].color_rmse < errs[0].color_rmse);
    }
}
