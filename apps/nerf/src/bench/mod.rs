//! `nerf bench`: wall-clock timings of the main jobs, printed beside their error so a
//! speed-up that loses accuracy shows.

pub mod hash_grid_rows;
pub mod memory;
pub mod mlp_flops;
pub mod pytorch_reference;
pub mod row;

use std::time::Instant;

use anyhow::Result;
use candle_core::Device;
use serde::Serialize;

pub use crate::bench::hash_grid_rows::RowGroup;
use crate::bench::hash_grid_rows::{
    bench_gemm, gemm_sizes, hash_grid_rows, render_throughput, GemmRates, MachineRates,
};
use crate::bench::memory::bench_table_reads;
use crate::bench::mlp_flops::{forward_flop_per_sample, mlp_throughput, TRAIN_FACTOR};
pub use crate::bench::pytorch_reference::{pytorch_seconds, ReferenceWork};
pub use crate::bench::row::{mean_psnr_of_views, BenchResult, LegoBench, Throughput};
use crate::render::scene::render_views;
use crate::timing::{fastest, time_runs};
use nerf::config::{Config, TrainingConfig};
use nerf::core::camera::PerspectiveCamera;
use nerf::core::image::RgbImage;
use nerf::core::metrics::mean;
use nerf::render::view::{render_view, Pipeline, RenderedView};
use nerf::train::model::{Optimizer, TrainModel};

/// Machine facts printed with every table.
#[derive(Debug, Clone, Serialize)]
pub struct MachineInfo {
    /// Threads in rayon's global pool (`rayon::current_num_threads`).
    pub threads: usize,
    /// Build profile: `release` or `debug`.
    pub profile: &'static str,
    /// CPU model from /proc/cpuinfo (`unknown` when unreadable).
    pub cpu: String,
}

/// This machine: CPU model (from /proc/cpuinfo), threads Candle uses, build profile.
pub fn machine_info() -> MachineInfo {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into());
    MachineInfo {
        threads: rayon::current_num_threads(),
        profile: if cfg!(debug_assertions) {
            "debug"
        } else {
            "release"
        },
        cpu,
    }
}

/// Times the box render (all surround views of `config`) `repeats` times and returns the best
/// time with the last run's frames; [`run_benchmarks`] fills in the error column (frame 0
/// against the float64 recomputation).
pub fn bench_sdf_render(
    config: &Config,
    repeats: usize,
    device: &Device,
) -> Result<(BenchResult, Vec<RenderedView>)> {
    let field = config.sdf_field(device)?;
    let render = config.render_settings()?;
    let cameras = config.surround_cameras();
    let size = config.image_size();
    let (runs, frames) = time_runs(repeats, || {
        render_views(&render.with(&field), &cameras, size, device)
    })?;
    let (w, h) = size;
    let work = format!(
        "{} frames {}x{} x {} points",
        cameras.len(),
        w,
        h,
        render.sampler.samples_per_ray()
    );
    Ok((
        BenchResult {
            name: "box render".into(),
            work,
            seconds: fastest(&runs),
            runs,
            pytorch_seconds: pytorch_seconds(ReferenceWork::Box(
                cameras.len(),
                w,
                h,
                render.sampler.samples_per_ray(),
            )),
            error: None,
            throughput: None,
        },
        frames,
    ))
}

/// Times the whole `nerf render` job of the SDF `config` (grid, rays, point cloud, every
/// surround frame, depth and GIF, written into a temporary directory), best of `repeats`,
/// against PyTorch's render of the frames alone.
pub fn bench_box_command(config: &Config, repeats: usize, device: &Device) -> Result<BenchResult> {
    let dir = std::env::temp_dir().join(format!("nerf-bench-{}", std::process::id()));
    let timed = time_runs(repeats, || {
        crate::render::scene::render_sdf_scene(config, &dir, false, device)
    });
    let _ = std::fs::remove_dir_all(&dir);
    let (runs, written) = timed?;
    let (w, h) = config.image_size();
    let (n, s) = (config.cameras.n_poses, config.sampler.n_pts_per_ray);
    Ok(BenchResult {
        name: "box command (all outputs)".into(),
        work: format!(
            "`nerf render`: {} files, {n} frames {w}x{h} x {s} points, point cloud, GIF",
            written.len()
        ),
        seconds: fastest(&runs),
        runs,
        pytorch_seconds: pytorch_seconds(ReferenceWork::Box(n, w, h, s)),
        error: None,
        throughput: None,
    })
}

/// Steps of the box fit timed per repeat by [`bench_train_box`].
pub const BOX_FIT_STEPS: usize = 40;

/// The box fit of the built-in `train_box` config (256x256 targets of another box, rendered
/// in memory; 4096 rays x 64 points per step, forward, backward, Adam): the mean step over
/// [`BOX_FIT_STEPS`] steps, best of `repeats` (the fit's accuracy is tested, not timed
/// here: `apps/nerf/tests/homework.rs` and `tests/sdf_gradients.rs`).
pub fn bench_train_box(repeats: usize, device: &Device) -> Result<BenchResult> {
    use nerf::train::fit_sdf::{fit_sdf, SdfView};
    let truth = Config::load(
        "train_box",
        &[
            "implicit_function.sdf.center.val=[0.1,-0.1,0.05]".into(),
            "implicit_function.sdf.side_lengths.val=[1.7,1.3,1.6]".into(),
        ],
    )?;
    let (w, h) = truth.image_size();
    let field = truth.sdf_field(device)?;
    let cameras = truth.data_cameras()?;
    let (sampler, renderer) = (truth.sampler()?, truth.renderer()?);
    let views = cameras
        .iter()
        .map(|(_, camera, _)| {
            let pipeline = Pipeline::new(&field, &*sampler, &renderer);
            let image = render_view(&pipeline, &nerf::Camera::from(*camera), (w, h), device)?.color;
            Ok(SdfView {
                camera: *camera,
                image,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let config = Config::load("train_box", &[])?;
    let mut settings = config.sdf_fit_settings()?;
    settings.num_epochs = BOX_FIT_STEPS / views.len();
    let mut runs = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        let fit = config.sdf_model(device)?;
        let report = fit_sdf(&fit, &views, &settings, device, |_, _, _| {})?;
        runs.push(report.seconds / report.steps as f64);
    }
    Ok(BenchResult {
        name: "train_box step".into(),
        work: format!(
            "{} rays x {} points of {w}x{h}, fwd+bwd+Adam (mean of {BOX_FIT_STEPS} steps)",
            settings.batch_size,
            sampler.samples_per_ray()
        ),
        seconds: fastest(&runs),
        runs,
        pytorch_seconds: pytorch_seconds(ReferenceWork::BoxStep(
            settings.batch_size,
            sampler.samples_per_ray(),
        )),
        error: None,
        throughput: None,
    })
}

/// Everything `nerf bench` measures.
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    /// The machine measured on.
    pub machine: MachineInfo,
    /// One result per benchmark run.
    pub results: Vec<BenchResult>,
}

/// Runs every benchmark that applies to `config`. The box render's error column is the largest
/// colour and depth difference of its frame 0 against the float64 recomputation
/// ([`nerf::eval::reference`]).
/// `only` picks groups of rows (all when empty).
pub fn run_benchmarks(
    config: &Config,
    repeats: usize,
    lego: Option<&LegoBench>,
    only: &[RowGroup],
    device: &Device,
) -> Result<BenchReport> {
    let wants = |g: RowGroup| only.is_empty() || only.contains(&g);
    // The matrix-multiply rates first: every NeRF row reports its fraction of them.
    let (gemm_rows, rates) = if wants(RowGroup::Matmul) {
        let (gemm_repeats, square) = gemm_sizes(lego.is_some_and(|l| l.quick));
        let (rows, rates) = bench_gemm(gemm_repeats, square);
        (rows, Some(rates))
    } else {
        (Vec::new(), None)
    };
    // And the random-read rate: every hash-grid row reports its table traffic's fraction of it.
    let (memory_rows, table_reads) = match lego {
        Some(l) if wants(RowGroup::Memory) => {
            let (rows, all_levels) = bench_table_reads(gemm_sizes(l.quick).0);
            (rows, Some(all_levels))
        }
        _ => (Vec::new(), None),
    };
    let machine = MachineRates {
        gemm: rates.as_ref(),
        table_reads,
    };
    let mut results = Vec::new();
    if wants(RowGroup::Base) {
        results = base_rows(config, repeats, lego, machine, device)?;
    }
    results.extend(gemm_rows);
    results.extend(memory_rows);
    if let Some(lego) = lego {
        results.extend(hash_grid_rows(lego, only, machine, device)?);
    }
    Ok(BenchReport {
        machine: machine_info(),
        results,
    })
}

/// The rows before the hash-grid ones ([`RowGroup::Base`]).
fn base_rows(
    config: &Config,
    repeats: usize,
    lego: Option<&LegoBench>,
    rates: MachineRates,
    device: &Device,
) -> Result<Vec<BenchResult>> {
    let (mut result, frames) = bench_sdf_render(config, repeats, device)?;
    let volume = config.sdf_volume()?;
    let cam = config.surround_cameras()[0];
    let (colors, depths) = nerf::eval::reference::render_image(
        &volume,
        &nerf::Camera::from(cam),
        config.image_size(),
        &config.stratified_sampler()?,
    );
    let max_abs = |a: &[f32], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (*x as f64 - y).abs())
            .fold(0.0, f64::max)
    };
    result.error = Some(format!(
        "max colour error {:.1e}, max depth error {:.1e} vs float64",
        max_abs(&frames[0].color.data, &colors),
        max_abs(&frames[0].depth, &depths)
    ));
    let mut results = vec![result];
    if !lego.is_some_and(|l| l.quick) {
        results.push(bench_box_command(config, repeats, device)?);
    }
    results.push(bench_train_box(repeats, device)?);
    if let Some(lego) = lego {
        if lego.checkpoint.is_file() {
            results.extend(bench_trained_nerf(lego, rates, device)?);
        } else {
            nerf::core::term::note(&format!(
                "skipping the trained-NeRF benchmark: checkpoint {} not found",
                lego.checkpoint.display()
            ));
        }
    }
    results.extend(bench_nerf(
        &Config::load("nerf_lego", &[])?,
        repeats,
        rates.gemm,
        device,
    )?);
    Ok(results)
}

/// NeRF throughput with the homework model (seeded initial weights; timing does not depend on
/// them): one training step (batch_size rays × n_pts_per_ray, forward, backward, Adam) and one
/// rendered frame at the config's size, each with its GFLOP/s against the run's gemm `rates`
/// ([`crate::bench::mlp_flops`]). Errors are not measured here (`nerf eval` does that).
pub fn bench_nerf(
    config: &Config,
    repeats: usize,
    rates: Option<&GemmRates>,
    device: &Device,
) -> Result<Vec<BenchResult>> {
    use rand::SeedableRng;
    let spec = config.field_spec()?;
    let training = config.training()?;
    let job = "time a NeRF training step";
    let batch_size = TrainingConfig::required(training.batch_size, "batch_size", job)?;
    let lr = TrainingConfig::required(training.lr, "lr", job)?;
    let state = TrainModel::seeded(&*spec, 0, device)?;
    let sampler = config.sampler()?;
    let renderer = config.renderer()?;
    let (w, h) = config.image_size();
    let camera = nerf::core::camera::surround_cameras(4.0, 20, glam::DVec3::Z, 2.0)[0];
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    let mut adam = Optimizer::new(&state, lr)?;
    let (step_runs, ()) = time_runs(repeats, || {
        let pixels = nerf::core::rays::random_pixel_indices(w, h, batch_size, &mut rng);
        let rays =
            nerf::core::rays::Rays::for_pixels(&nerf::Camera::from(camera), w, h, &pixels, device)?;
        let target = candle_core::Tensor::full(0.5f32, (pixels.len(), 3), device)?;
        let field = state.training_field(0.0);
        let out = renderer.render(&*field, sampler.as_ref(), &rays, Some(&mut rng))?;
        let loss = out.color.sub(&target)?.sqr()?.mean_all()?;
        adam.step(&loss.backward()?)?;
        Ok(())
    })?;
    let (frame_runs, _) = time_runs(repeats.clamp(1, 2), || {
        let field = state.render_field();
        render_view(
            &Pipeline::new(&*field, &*sampler, &renderer),
            &nerf::Camera::from(camera),
            (w, h),
            device,
        )
    })?;
    let forward = forward_flop_per_sample(&spec.parameter_shapes()?);
    let step_samples = batch_size * sampler.samples_per_ray();
    let frame_samples = w * h * sampler.samples_per_ray();
    let step_seconds = fastest(&step_runs);
    let frame_seconds = fastest(&frame_runs);
    Ok(vec![
        BenchResult {
            name: "NeRF training step".into(),
            work: format!(
                "{} rays x {} points, fwd+bwd+Adam",
                batch_size,
                sampler.samples_per_ray()
            ),
            seconds: step_seconds,
            runs: step_runs,
            pytorch_seconds: pytorch_seconds(ReferenceWork::Step(
                batch_size,
                sampler.samples_per_ray(),
            )),
            error: None,
            throughput: Some(mlp_throughput(
                (batch_size, step_samples, step_samples),
                TRAIN_FACTOR * forward,
                step_seconds,
                rates,
            )),
        },
        BenchResult {
            name: "NeRF render".into(),
            work: format!(
                "1 frame {w}x{h} x {} points, dense, untrained",
                sampler.samples_per_ray()
            ),
            seconds: frame_seconds,
            runs: frame_runs,
            pytorch_seconds: pytorch_seconds(ReferenceWork::Frame(w, h, sampler.samples_per_ray())),
            error: None,
            throughput: Some(mlp_throughput(
                (w * h, frame_samples, frame_samples),
                forward,
                frame_seconds,
                rates,
            )),
        },
    ])
}

/// The `lego` render config with every acceleration off: dense rendering as the homework.
pub fn dense_overrides() -> Vec<String> {
    vec![
        "renderer.early_termination=0".into(),
        "renderer.occupancy_grid=null".into(),
    ]
}

/// Frames of one configuration, with per-frame seconds and the time to load the checkpoint (and
/// build or load its grid).
struct RenderRun {
    frames: Vec<RenderedView>,
    runs: Vec<f64>,
    load_seconds: f64,
}

/// The first `lego.views` test cameras and their images, or the surround cameras without
/// ground truth when the dataset cannot be read.
/// The pytorch3d cameras of the first `views` frames of a NeRF-synthetic split; an error for a
/// capture, whose cameras are not pinholes on the homework's grid.
pub(crate) fn lego_cameras(
    dataset: &nerf::io::dataset::Dataset,
    views: usize,
) -> Result<Vec<PerspectiveCamera>> {
    dataset
        .frames
        .iter()
        .take(views)
        .map(|f| {
            f.camera.pinhole().copied().ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: the lego benchmark needs a NeRF-synthetic scene",
                    f.file_path.display()
                )
            })
        })
        .collect()
}

fn bench_views(
    lego: &LegoBench,
    config: &Config,
) -> Result<(Vec<PerspectiveCamera>, Option<Vec<RgbImage>>)> {
    let (w, h) = config.image_size();
    Ok(
        match nerf::io::dataset::Dataset::load(
            &lego.data_dir,
            nerf::io::dataset::Split::Test,
            w,
            h,
            config.renderer.white_background,
        ) {
            Ok(d) => (
                lego_cameras(&d, lego.views)?,
                Some(d.images.into_iter().take(lego.views).collect()),
            ),
            Err(e) => {
                nerf::core::term::note(&format!(
                    "trained-NeRF benchmark without ground truth ({e})"
                ));
                (
                    config
                        .surround_cameras()
                        .into_iter()
                        .take(lego.views)
                        .collect(),
                    None,
                )
            }
        },
    )
}

/// Loads `checkpoint` with `config` and renders every camera once, timing each.
fn render_run(
    config: &Config,
    checkpoint: &std::path::Path,
    cameras: &[PerspectiveCamera],
    device: &Device,
) -> Result<RenderRun> {
    let (w, h) = config.image_size();
    let n = cameras.len();
    let t = Instant::now();
    let field = config.load_field(checkpoint, device)?;
    let load_seconds = t.elapsed().as_secs_f64();
    let field = &*field;
    let render = config.render_settings()?;
    let mut frames = Vec::with_capacity(n);
    let mut runs = Vec::with_capacity(n);
    for cam in cameras {
        let t = Instant::now();
        frames.push(render_view(
            &render.with(field),
            &nerf::Camera::from(*cam),
            (w, h),
            device,
        )?);
        runs.push(t.elapsed().as_secs_f64());
    }
    Ok(RenderRun {
        frames,
        runs,
        load_seconds,
    })
}

/// The shipped checkpoint rendered densely and with the accelerations of the `lego` config
/// (occupancy grid, early termination): time per frame, PSNR of each against the ground truth,
/// and of the accelerated render against the dense one.
pub fn bench_trained_nerf(
    lego: &LegoBench,
    rates: MachineRates,
    device: &Device,
) -> Result<Vec<BenchResult>> {
    let fast_config = Config::load("lego", &[])?;
    let dense_config = Config::load("lego", &dense_overrides())?;
    let (w, h) = fast_config.image_size();
    let (cameras, truth) = bench_views(lego, &fast_config)?;
    let n = cameras.len();
    let render_all = |config: &Config| render_run(config, &lego.checkpoint, &cameras, device);
    let RenderRun {
        frames: dense,
        runs: dense_runs,
        ..
    } = render_all(&dense_config)?;
    let RenderRun {
        frames: fast,
        runs: fast_runs,
        load_seconds: grid_seconds,
    } = render_all(&fast_config)?;
    let dense_colors: Vec<RgbImage> = dense.iter().map(|f| f.color.clone()).collect();
    let vs_dense = mean_psnr_of_views(&fast, &dense_colors);
    let counts = fast
        .iter()
        .fold(nerf::render::skipping::SampleCounts::default(), |a, f| {
            a + f.samples
        });
    let evaluated = 100.0 * counts.evaluated_fraction();
    let (dense_error, fast_error) = match &truth {
        Some(t) => {
            let (d, f) = (mean_psnr_of_views(&dense, t), mean_psnr_of_views(&fast, t));
            (
                format!("PSNR {d:.2} dB vs ground truth ({n} test views)"),
                format!(
                    "PSNR {f:.2} dB vs ground truth ({:+.2} dB vs dense); {vs_dense:.1} dB vs the dense render; field at {evaluated:.1}% of samples",
                    f - d
                ),
            )
        }
        None => (
            "no ground truth".to_string(),
            format!("{vs_dense:.1} dB vs the dense render; field at {evaluated:.1}% of samples"),
        ),
    };
    let points = fast_config.sampler.n_pts_per_ray;
    let forward = forward_flop_per_sample(&fast_config.field_spec()?.parameter_shapes()?);
    let dense_drawn = n * w * h * points;
    let dense_throughput = mlp_throughput(
        (n * w * h, dense_drawn, dense_drawn),
        forward,
        dense_runs.iter().sum(),
        rates.gemm,
    );
    let fast_throughput = mlp_throughput(
        (n * w * h, counts.total, counts.evaluated),
        forward,
        fast_runs.iter().sum(),
        rates.gemm,
    );
    let mut rows = ngp_rows(&cameras, truth.as_deref(), lego.quick, rates, device)?;
    rows.splice(0..0, [
        BenchResult {
            name: "trained NeRF render, dense".into(),
            work: format!("1 frame {w}x{h} x {points} points (mean of {n})"),
            seconds: mean(&dense_runs),
            runs: dense_runs,
            pytorch_seconds: pytorch_seconds(ReferenceWork::Frame(w, h, points)),
            error: Some(dense_error),
            throughput: Some(dense_throughput),
        },
        BenchResult {
            name: "trained NeRF render, occupancy grid + early termination".into(),
            work: format!(
                "1 frame {w}x{h} x {points} points (mean of {n}; loading the checkpoint and its grid took {grid_seconds:.3} s once)"
            ),
            seconds: mean(&fast_runs),
            runs: fast_runs,
            pytorch_seconds: pytorch_seconds(ReferenceWork::Frame(w, h, points)),
            error: Some(fast_error),
            throughput: Some(fast_throughput),
        },
    ]);
    Ok(rows)
}

/// The shipped hash-grid model ([`nerf::config::SHIPPED_NGP_CHECKPOINT`], config
/// `lego_ngp`), when present: a frame of each camera, and (unless `quick`) the whole
/// `nerf render` command (20 surround views and the GIF, into a temporary directory).
fn ngp_rows(
    cameras: &[PerspectiveCamera],
    truth: Option<&[RgbImage]>,
    quick: bool,
    rates: MachineRates,
    device: &Device,
) -> Result<Vec<BenchResult>> {
    let checkpoint = std::path::Path::new(nerf::config::SHIPPED_NGP_CHECKPOINT);
    if !checkpoint.is_file() {
        return Ok(Vec::new());
    }
    let config = Config::load("lego_ngp", &[])?;
    let (w, h) = config.image_size();
    let points = config.sampler.n_pts_per_ray;
    let n = cameras.len();
    let run = render_run(&config, checkpoint, cameras, device)?;
    let counts = run
        .frames
        .iter()
        .fold(nerf::render::skipping::SampleCounts::default(), |a, f| {
            a + f.samples
        });
    let evaluated = 100.0 * counts.evaluated_fraction();
    let error = match truth {
        Some(t) => format!(
            "PSNR {:.2} dB vs ground truth; field at {evaluated:.1}% of samples",
            mean_psnr_of_views(&run.frames, t)
        ),
        None => format!("field at {evaluated:.1}% of samples"),
    };
    let flops = crate::bench::hash_grid_rows::NgpFlops::of_config(&config)?;
    let throughput = render_throughput(&flops, &run.frames, &run.runs, (w, h), rates);
    let frame_row = BenchResult {
        name: "hash-grid render (lego_ngp), grid + early termination".into(),
        work: format!("1 frame {w}x{h} x {points} points (mean of {n})"),
        seconds: mean(&run.runs),
        runs: run.runs,
        pytorch_seconds: None,
        error: Some(error),
        throughput: Some(throughput),
    };
    if quick {
        return Ok(vec![frame_row]);
    }
    let dir = std::env::temp_dir().join(format!("nerf-bench-ngp-{}", std::process::id()));
    let timed = time_runs(2, || {
        crate::render::scene::render_nerf_scene(&config, checkpoint, &dir, false, device)
    });
    let _ = std::fs::remove_dir_all(&dir);
    let (command_runs, _) = timed?;
    let poses = config.cameras.n_poses;
    Ok(vec![
        frame_row,
        BenchResult {
            name: "hash-grid render command (lego_ngp)".into(),
            work: format!(
                "`nerf render`: load, {poses} frames {w}x{h} x {points} points, GIF (best of 2)"
            ),
            seconds: fastest(&command_runs),
            runs: command_runs,
            pytorch_seconds: None,
            error: None,
            throughput: None,
        },
    ])
}

/// The report as a Markdown table.
pub fn format_table(report: &BenchReport) -> String {
    let m = &report.machine;
    let mut s = format!(
        "machine: {} | threads: {} | profile: {}\n\n",
        m.cpu, m.threads, m.profile
    );
    s += "| benchmark | work | time (s) | PyTorch CPU (s) | ratio | error | throughput |\n|---|---|---|---|---|---|---|\n";
    for r in &report.results {
        let (pt, ratio) = match r.pytorch_seconds {
            Some(p) => (format!("{p:.3}"), format!("{:.2}x", r.seconds / p)),
            None => ("-".into(), "-".into()),
        };
        s += &format!(
            "| {} | {} | {:.3} | {} | {} | {} | {} |\n",
            r.name,
            r.work,
            r.seconds,
            pt,
            ratio,
            r.error.as_deref().unwrap_or("-"),
            r.throughput
                .as_ref()
                .map_or_else(|| "-".to_string(), Throughput::describe)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_has_a_throughput_column() {
        let row = |throughput| BenchResult {
            name: "row".into(),
            work: "work".into(),
            seconds: 1.0,
            runs: vec![1.0],
            pytorch_seconds: None,
            error: None,
            throughput,
        };
        let report = BenchReport {
            machine: machine_info(),
            results: vec![
                row(None),
                row(Some(Throughput {
                    evaluated_samples_per_second: Some(2.5e6),
                    gflops: 40.0,
                    fraction_of_mlp_gemm: Some(0.4),
                    ..Throughput::default()
                })),
            ],
        };
        let table = format_table(&report);
        assert!(table.contains("| error | throughput |"), "{table}");
        assert!(table.contains("| - | - |\n"), "{table}");
        assert!(
            table.contains(
                "2.50M evaluated samples/s; 40.0 GFLOP/s = 40.0% of the MLP-shaped gemm |"
            ),
            "{table}"
        );
        // JSON leaves the field out of rows without it.
        let json = serde_json::to_value(&report).unwrap();
        assert!(json["results"][0].get("throughput").is_none());
        assert_eq!(json["results"][1]["throughput"]["gflops"], 40.0);
    }
}
