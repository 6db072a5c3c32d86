//! `nerf bench`'s hash-grid rows: training throughput (evaluated samples per second at the
//! shipped `nerf_lego_ngp` config and at 2^18 samples per step), a 400×400 frame of the
//! shipped `lego_ngp_400` model, and this machine's own f32 matrix-multiply rate measured in
//! the same run with the same `gemm` the fused kernels use, so that each hash-grid row can say
//! which fraction of the machine it reaches.

use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use candle_core::Device;
use rand::SeedableRng;
use rayon::prelude::*;

use crate::bench::row::{mean_psnr_of_views, BenchResult, LegoBench, Throughput};
use crate::timing::fastest;
use nerf::config::Config;
use nerf::core::camera::Camera;
use nerf::field::ngp::NgpParams;
use nerf::field::ngp::{GEO_FEATURES, HIDDEN};
use nerf::hash_grid::spherical_harmonics::SH_DIM;
use nerf::io::dataset::{Dataset, Split};
use nerf::kernels::gemm::gemm_f32;
use nerf::render::occupancy::OccupancyGrid;
use nerf::render::skipping::SampleCounts;
use nerf::render::view::{render_view, RenderedView};
use nerf::train::model::{Optimizer, TrainModel};
use nerf::train::step::{train_step, TrainRng};

/// Rows per task of the MLP-shaped product timed with one `gemm` call per task on the calling
/// thread, as the fused NGP MLP ([`nerf::hash_grid::ngp_mlp`]) runs it.
const MLP_ROWS_PER_TASK: usize = 256;

/// The matrix-multiply rates measured in this run (GFLOP/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GemmRates {
    /// The faster of the two MLP-shaped products (65536×64 by 64×64).
    pub mlp: f64,
    /// The large square product.
    pub square: f64,
}

impl GemmRates {
    /// A throughput of `gflops` with its fractions of `rates` (none without them).
    pub fn throughput(rates: Option<&Self>, gflops: f64) -> Throughput {
        Throughput {
            gflops,
            fraction_of_mlp_gemm: rates.map(|r| gflops / r.mlp),
            fraction_of_square_gemm: rates.map(|r| gflops / r.square),
            ..Throughput::default()
        }
    }
}

/// What the same run measured the machine can do, for the hash-grid rows' fractions: the gemm
/// rates (`--only matmul`) and the random row reads per second from a 16-level table
/// (`--only memory`); either is `None` when its rows were not run.
#[derive(Debug, Clone, Copy, Default)]
pub struct MachineRates<'a> {
    /// The matrix-multiply rates.
    pub gemm: Option<&'a GemmRates>,
    /// Random table rows read per second ([`crate::bench::memory::bench_table_reads`]).
    pub table_reads: Option<f64>,
}

/// Floating-point operations of the NGP field ([`nerf::field::ngp`]), counted from its layer
/// sizes; a multiply-add counts 2.
///
/// Per evaluated sample, forward, with `E = L·F` encoding features (`L` levels, `F` features
/// per level), hidden width `H` ([`HIDDEN`], 64) and `G` geometry features ([`GEO_FEATURES`],
/// 15):
///
/// * hash encoding: each level blends the features of the 8 corners of the sample's cell
///   with trilinear weights: `L · 8 · F` multiply-adds, `2·8·L·F` FLOP (the weights themselves,
///   a product of three factors per corner, add `L · 8 · 2`; the integer hashing and the
///   gathers are not counted);
/// * density MLP: `E → H` and `H → 1 + G`: `2·(E·H + H·(1+G))`;
/// * colour MLP: the geometry half of its first layer `G → H` (`2·G·H`; the direction half
///   depends on the ray only, below), `H → H` and `H → 3`: `2·(G·H + H·H + 3·H)`;
/// * biases and activations (`H + 1 + G + H + H + 3` values, about one FLOP each) are left
///   out: they are a few percent and not matrix work.
///
/// At the shipped sizes (`L = 16`, `F = 2`, `H = 64`, `G = 15`): encoding 512 + 256, density
/// MLP 4096 + 2048, colour MLP 1920 + 8192 + 384: **17 408 FLOP forward** per sample.
///
/// Per ray, forward: the direction half of the colour MLP's first layer on the 16
/// spherical-harmonics coefficients ([`SH_DIM`]): `2·16·H` = 2048 FLOP.
///
/// Training (forward and backward): each layer's backward pass is two products the size of
/// its forward one (the input's gradient and the weight's gradient), so forward + backward
/// counts 3× forward per sample (the encoding's backward scatters `L·8·F` weighted gradients
/// into the table, again about its forward count). The per-ray part needs the weight's
/// gradient only: 2× forward. The fused MLP's backward pass recomputes the forward
/// activations ([`nerf::hash_grid::ngp_mlp`]); that recomputation is not useful work and is
/// not counted, so the fractions below are of useful work.
///
/// Table traffic, counted the same way: a sample reads the rows of its 8 corners on each
/// level forward (`8·L`, 128 at the shipped sizes), and training adds its gradient into the
/// same rows backward (another `8·L` random row accesses). The sparse Adam's row updates are
/// not counted: it walks the touched rows in address order, not at random.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NgpFlops {
    /// FLOP per evaluated sample, forward.
    pub forward_per_sample: f64,
    /// FLOP per ray, forward (the per-ray part of the colour MLP).
    pub forward_per_ray: f64,
    /// Random table rows a sample reads forward (`8·L`).
    pub table_rows_per_sample: f64,
}

impl NgpFlops {
    /// The count for `n_levels` levels of `n_features` features each.
    pub fn new(n_levels: usize, n_features: usize) -> Self {
        let (l, f) = (n_levels as f64, n_features as f64);
        let (e, h, g) = (l * f, HIDDEN as f64, GEO_FEATURES as f64);
        let encoding = 2.0 * 8.0 * l * f + 2.0 * 8.0 * l;
        let density = 2.0 * (e * h + h * (1.0 + g));
        let colour = 2.0 * (g * h + h * h + 3.0 * h);
        Self {
            forward_per_sample: encoding + density + colour,
            forward_per_ray: 2.0 * SH_DIM as f64 * h,
            table_rows_per_sample: 8.0 * l,
        }
    }

    /// The count of the NGP field of `config` (an error for another field kind).
    pub fn of_config(config: &Config) -> Result<Self> {
        match config.implicit_function.get::<NgpParams>() {
            Some(n) => Ok(Self::new(n.n_levels, n.n_features_per_level)),
            None => anyhow::bail!("the FLOP count is of hash-grid (type: ngp) fields only"),
        }
    }

    /// FLOP per evaluated sample, forward and backward (3× forward).
    pub fn train_per_sample(&self) -> f64 {
        3.0 * self.forward_per_sample
    }

    /// FLOP per ray, forward and backward (2× forward).
    pub fn train_per_ray(&self) -> f64 {
        2.0 * self.forward_per_ray
    }

    /// Random table rows a training sample touches: read forward, added into backward.
    pub fn train_table_rows_per_sample(&self) -> f64 {
        2.0 * self.table_rows_per_sample
    }
}

/// Table rows per second and, with the run's random-read rate `reads` (rows per second), their
/// fraction of it.
fn table_traffic(rows_per_second: f64, reads: Option<f64>) -> (Option<f64>, Option<f64>) {
    let fraction = reads.filter(|r| *r > 0.0).map(|r| rows_per_second / r);
    (Some(rows_per_second), fraction)
}

/// Best seconds of `calls` calls of `f`, over `repeats` repeats, divided by `calls`.
fn best_per_call(repeats: usize, calls: usize, mut f: impl FnMut()) -> Vec<f64> {
    f();
    (0..repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            for _ in 0..calls {
                f();
            }
            t.elapsed().as_secs_f64() / calls as f64
        })
        .collect()
}

/// A matrix-product row: `flop` per call, runs in seconds per call.
fn gemm_row(name: &str, work: String, flop: f64, runs: Vec<f64>) -> (BenchResult, f64) {
    let seconds = fastest(&runs);
    let gflops = flop / seconds / 1e9;
    (
        BenchResult {
            name: name.into(),
            work,
            seconds,
            runs,
            pytorch_seconds: None,
            error: None,
            throughput: Some(Throughput {
                gflops,
                ..Throughput::default()
            }),
        },
        gflops,
    )
}

/// This machine's f32 matrix-multiply rate with the `gemm` crate as the fused kernels call it
/// ([`gemm_f32`]): the MLP-shaped product 65536×64 by 64×64 in 256-row tasks on rayon's
/// threads (as [`nerf::hash_grid::ngp_mlp`] runs it) and in one call on `gemm`'s own threads,
/// and a square product (`square`³). Best of `repeats`.
pub fn bench_gemm(repeats: usize, square: usize) -> (Vec<BenchResult>, GemmRates) {
    let (m, k, n) = (65536, HIDDEN, HIDDEN);
    let lhs: Vec<f32> = (0..m * k)
        .map(|i| ((i % 97) as f32 - 48.0) / 97.0)
        .collect();
    let rhs: Vec<f32> = (0..k * n)
        .map(|i| ((i % 89) as f32 - 44.0) / 89.0)
        .collect();
    let mut dst = vec![0.0f32; m * n];
    let flop = 2.0 * (m * k * n) as f64;
    let tasks = best_per_call(repeats, 10, || {
        dst.par_chunks_mut(MLP_ROWS_PER_TASK * n)
            .zip(lhs.par_chunks(MLP_ROWS_PER_TASK * k))
            .for_each(|(d, l)| {
                let rows = d.len() / n;
                gemm_f32((rows, n, k), d, n, false, l, (k, 1), &rhs, (n, 1), false)
            })
    });
    let one_call = best_per_call(repeats, 10, || {
        gemm_f32(
            (m, n, k),
            &mut dst,
            n,
            false,
            &lhs,
            (k, 1),
            &rhs,
            (n, 1),
            true,
        )
    });
    let sq: Vec<f32> = (0..square * square)
        .map(|i| ((i % 101) as f32 - 50.0) / 101.0)
        .collect();
    let mut sq_dst = vec![0.0f32; square * square];
    let sq_runs = best_per_call(repeats, 2, || {
        let s = square;
        gemm_f32(
            (s, s, s),
            &mut sq_dst,
            s,
            false,
            &sq,
            (s, 1),
            &sq,
            (s, 1),
            true,
        )
    });
    let threads = rayon::current_num_threads();
    let (a, rate_tasks) = gemm_row(
        "f32 matmul, MLP-shaped, 256-row tasks",
        format!(
            "{m}x{k} by {k}x{n} as {} tasks of {MLP_ROWS_PER_TASK} rows on {threads} threads (as the fused NGP MLP), per product",
            m / MLP_ROWS_PER_TASK
        ),
        flop,
        tasks,
    );
    let (b, rate_one) = gemm_row(
        "f32 matmul, MLP-shaped, one call",
        format!("{m}x{k} by {k}x{n}, one gemm call on {threads} threads, per product"),
        flop,
        one_call,
    );
    let (c, rate_square) = gemm_row(
        "f32 matmul, square",
        format!("{square}x{square} by {square}x{square}, one gemm call on {threads} threads"),
        2.0 * (square as f64).powi(3),
        sq_runs,
    );
    (
        vec![a, b, c],
        GemmRates {
            mlp: rate_tasks.max(rate_one),
            square: rate_square,
        },
    )
}

/// How many training steps the hash-grid training rows take.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepCounts {
    /// Untimed steps first (the ray count settles on the samples per step).
    pub warmup: usize,
    /// Timed steps.
    pub timed: usize,
}

/// Hash-grid training throughput: Adam steps of the built-in `nerf_lego_ngp` config (rays
/// from all 128×128 training images of `data_dir`, random backgrounds, occupancy grid and early
/// termination, the rays of each step adapted to evaluate about `samples_per_step` samples;
/// the config's 16384 when `None`), starting from the shipped hash-grid checkpoint and its
/// occupancy grid when it exists (the grid as it is late in training; else from seeded
/// weights with every cell occupied). The grid is updated every `update_interval` (8) steps
/// counted from the first warm-up step, as in training and inside the timed steps (the
/// default step counts time one update per 8 steps). `steps.warmup` untimed steps first (the first ones jump
/// the ray count to the target), then `steps.timed` timed ones; the row's seconds are the
/// mean step and its throughput is over all timed steps.
pub fn bench_ngp_training(
    data_dir: &Path,
    samples_per_step: Option<usize>,
    steps: StepCounts,
    rates: MachineRates,
    device: &Device,
) -> Result<BenchResult> {
    let overrides: Vec<String> = samples_per_step
        .map(|n| vec![format!("training.samples_per_step={n}")])
        .unwrap_or_default();
    let config = Config::load("nerf_lego_ngp", &overrides)?;
    let settings = config.train_settings()?;
    let flops = NgpFlops::of_config(&config)?;
    let (w, h) = config.image_size();
    let dataset = Dataset::load(
        data_dir,
        Split::Train,
        w,
        h,
        config.renderer.white_background,
    )?;
    let checkpoint = Path::new(nerf::config::SHIPPED_NGP_CHECKPOINT);
    let (mut model, start) = if checkpoint.is_file() {
        (
            config.load_model(checkpoint, device)?.0,
            "from the shipped lego_ngp checkpoint and its grid",
        )
    } else {
        let mut model = TrainModel::seeded(&*settings.model, settings.seed, device)?;
        if let Some(schedule) = &settings.grid {
            model.occupancy = Some(OccupancyGrid::new(&schedule.grid)?);
        }
        (model, "from seeded weights, every grid cell occupied")
    };
    let mut adam = Optimizer::new(&model, settings.lr)?;
    let mut rng = TrainRng::seed_from_u64(settings.seed);
    let mut step = settings.step.clone();
    let target = settings.samples_per_step;
    let n_images = dataset.images.len().max(1);
    let mut runs = Vec::with_capacity(steps.timed);
    let mut counts = SampleCounts::default();
    let mut rays_timed = 0usize;
    for k in 0..steps.warmup + steps.timed {
        let t = Instant::now();
        if let Some(schedule) = &settings.grid {
            if k % schedule.update_interval.max(1) == 0 {
                model.update_grid(false, schedule.decay as f32, &mut rng, device)?;
            }
        }
        let (loss, samples) = train_step(
            &model,
            &step,
            &dataset,
            k % n_images,
            &mut adam,
            &mut rng,
            device,
        )?;
        let seconds = t.elapsed().as_secs_f64();
        anyhow::ensure!(
            loss.is_finite(),
            "hash-grid training bench diverged: loss {loss}"
        );
        let rays = step.batch_size;
        if k >= steps.warmup {
            runs.push(seconds);
            counts = counts + samples;
            rays_timed += rays;
        }
        if let Some(target) = target {
            step.batch_size = if k < steps.warmup {
                // Straight to the count that would have hit the target.
                let ideal = rays as f64 * target as f64 / samples.evaluated.max(1) as f64;
                (ideal.round() as usize).clamp(64, settings.max_rays.max(64))
            } else {
                nerf::train::schedule::next_rays(rays, samples.evaluated, target, settings.max_rays)
            };
        }
    }
    let total: f64 = runs.iter().sum();
    let per_s = |n: usize| n as f64 / total.max(1e-12);
    let evaluated = per_s(counts.evaluated);
    let ray_rate = per_s(rays_timed);
    let gflops = (evaluated * flops.train_per_sample() + ray_rate * flops.train_per_ray()) / 1e9;
    let (table_rows_per_second, fraction_of_random_reads) = table_traffic(
        evaluated * flops.train_table_rows_per_sample(),
        rates.table_reads,
    );
    let throughput = Throughput {
        rays_per_second: Some(ray_rate),
        drawn_samples_per_second: Some(per_s(counts.total)),
        evaluated_samples_per_second: Some(evaluated),
        flop_per_evaluated_sample: Some(flops.train_per_sample()),
        table_rows_per_second,
        fraction_of_random_reads,
        ..GemmRates::throughput(rates.gemm, gflops)
    };
    let timed = runs.len().max(1);
    let target_text = target.map_or("the config's rays".to_string(), |t| format!("{t}"));
    Ok(BenchResult {
        name: format!(
            "hash-grid training (nerf_lego_ngp), {} samples/step",
            target.map_or("-".into(), |t| t.to_string())
        ),
        work: format!(
            "mean Adam step evaluating ~{target_text} samples ({} rays, {} evaluated of {} drawn a step on average), {w}x{h}, {start}; {} timed steps after {} warm-up",
            rays_timed / timed,
            counts.evaluated / timed,
            counts.total / timed,
            steps.timed,
            steps.warmup
        ),
        seconds: total / timed as f64,
        runs,
        pytorch_seconds: None,
        error: None,
        throughput: Some(throughput),
    })
}

/// A 400×400 frame of the shipped `lego_ngp_400` hash-grid model (`checkpoint`; its grid and
/// early termination, 256 samples per ray) for each of the first `views` test cameras of
/// `data_dir` (the surround cameras when the dataset cannot be read): mean seconds per frame,
/// rays, drawn and evaluated samples per second, and the PSNR against the test images.
pub fn bench_ngp_render_400(
    checkpoint: &Path,
    data_dir: &Path,
    views: usize,
    rates: MachineRates,
    device: &Device,
) -> Result<BenchResult> {
    let config = Config::load("lego_ngp_400", &[])?;
    let flops = NgpFlops::of_config(&config)?;
    let (w, h) = config.image_size();
    let (cameras, truth, which) = match Dataset::load_first(
        data_dir,
        Split::Test,
        w,
        h,
        config.renderer.white_background,
        Some(views),
    ) {
        Ok(d) => (
            d.frames
                .iter()
                .map(|f| f.camera.clone())
                .collect::<Vec<_>>(),
            Some(d.images),
            "test views",
        ),
        Err(_) => (
            config
                .surround_cameras()
                .into_iter()
                .take(views)
                .map(Camera::from)
                .collect(),
            None,
            "surround views",
        ),
    };
    let t = Instant::now();
    let field = config.load_field(checkpoint, device)?;
    let load = t.elapsed().as_secs_f64();
    let render = config.render_settings()?;
    let mut frames = Vec::with_capacity(cameras.len());
    let mut runs = Vec::with_capacity(cameras.len());
    for cam in &cameras {
        let t = Instant::now();
        frames.push(render_view(&render.with(&*field), cam, (w, h), device)?);
        runs.push(t.elapsed().as_secs_f64());
    }
    let counts = frames
        .iter()
        .fold(SampleCounts::default(), |a, f| a + f.samples);
    let throughput = render_throughput(&flops, &frames, &runs, (w, h), rates);
    let total: f64 = runs.iter().sum::<f64>().max(1e-12);
    let n = frames.len();
    let evaluated_pct = 100.0 * counts.evaluated_fraction();
    let error = match truth {
        Some(t) => format!(
            "PSNR {:.2} dB vs ground truth; field at {evaluated_pct:.1}% of samples",
            mean_psnr_of_views(&frames, &t)
        ),
        None => format!("field at {evaluated_pct:.1}% of samples"),
    };
    Ok(BenchResult {
        name: "hash-grid render 400x400 (lego_ngp_400), grid + early termination".into(),
        work: format!(
            "1 frame {w}x{h} x {} points (mean of {n} {which}; loading took {load:.3} s once)",
            config.sampler.n_pts_per_ray
        ),
        seconds: total / n.max(1) as f64,
        runs,
        pytorch_seconds: None,
        error: Some(error),
        throughput: Some(throughput),
    })
}

/// Groups of `nerf bench` rows (`--only`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RowGroup {
    /// The rows before the hash-grid ones: the box, its fit, the NeRF step and frames, the
    /// trained NeRF and the 128x128 hash-grid model.
    Base,
    /// The f32 matrix-multiply rates (without them, the NeRF and hash-grid rows have no fractions).
    Matmul,
    /// Random row reads from hash tables of one and of 16 levels (without them, the hash-grid
    /// rows have no fraction of the random-read rate).
    Memory,
    /// Hash-grid training at the shipped samples per step.
    NgpTrain,
    /// Hash-grid training at 2^18 samples per step.
    NgpTrainLarge,
    /// A 400x400 frame of the shipped lego_ngp_400.
    #[value(name = "ngp-render-400")]
    NgpRender400,
}

/// Samples per step of the larger hash-grid training row (2^18).
pub const LARGE_SAMPLES_PER_STEP: usize = 1 << 18;

/// The throughput of hash-grid `frames` of `w`×`h` rendered in `runs` seconds, counted with
/// `flops`, against the run's `rates`.
pub fn render_throughput(
    flops: &NgpFlops,
    frames: &[RenderedView],
    runs: &[f64],
    (w, h): (usize, usize),
    rates: MachineRates,
) -> Throughput {
    let counts = frames
        .iter()
        .fold(SampleCounts::default(), |a, f| a + f.samples);
    let total: f64 = runs.iter().sum::<f64>().max(1e-12);
    let rays = (w * h * frames.len()) as f64 / total;
    let evaluated = counts.evaluated as f64 / total;
    let gflops = (evaluated * flops.forward_per_sample + rays * flops.forward_per_ray) / 1e9;
    let (table_rows_per_second, fraction_of_random_reads) =
        table_traffic(evaluated * flops.table_rows_per_sample, rates.table_reads);
    Throughput {
        rays_per_second: Some(rays),
        drawn_samples_per_second: Some(counts.total as f64 / total),
        evaluated_samples_per_second: Some(evaluated),
        flop_per_evaluated_sample: Some(flops.forward_per_sample),
        table_rows_per_second,
        fraction_of_random_reads,
        ..GemmRates::throughput(rates.gemm, gflops)
    }
}

/// Repeats and the square product's side of the matrix-multiply rows: fewer and smaller
/// with `quick`.
pub fn gemm_sizes(quick: bool) -> (usize, usize) {
    if quick {
        (2, 512)
    } else {
        (5, 1024)
    }
}

/// Every hash-grid training and 400×400 row that `lego` allows, with their fractions of what
/// the run measured the `machine` can do: the training rows need the lego dataset, the
/// 400×400 row the `lego_ngp_400` checkpoint (each is skipped with a note when missing).
/// `lego.quick`: fewer steps.
pub fn hash_grid_rows(
    lego: &LegoBench,
    only: &[RowGroup],
    machine: MachineRates,
    device: &Device,
) -> Result<Vec<BenchResult>> {
    let wants = |g: RowGroup| only.is_empty() || only.contains(&g);
    let mut rows = Vec::new();
    let (mut shipped, mut large) = if lego.quick {
        let s = StepCounts {
            warmup: 2,
            timed: 2,
        };
        (s, s)
    } else {
        (
            StepCounts {
                warmup: 4,
                timed: 24,
            },
            StepCounts {
                warmup: 3,
                timed: 8,
            },
        )
    };
    if let Some(n) = lego.train_steps {
        (shipped.timed, large.timed) = (n, n);
    }
    let training = [
        (RowGroup::NgpTrain, None, shipped),
        (RowGroup::NgpTrainLarge, Some(LARGE_SAMPLES_PER_STEP), large),
    ];
    let training: Vec<_> = training.into_iter().filter(|t| wants(t.0)).collect();
    let has_data = lego.data_dir.join("transforms_train.json").is_file();
    if has_data {
        for (_, samples, steps) in training {
            rows.push(bench_ngp_training(
                &lego.data_dir,
                samples,
                steps,
                machine,
                device,
            )?);
        }
    } else if !training.is_empty() {
        nerf::core::term::note(&format!(
            "skipping the hash-grid training benchmark: no lego training split in {}",
            lego.data_dir.display()
        ));
    }
    let checkpoint = Config::load("lego_ngp_400", &[])?.checkpoint(None);
    let render = wants(RowGroup::NgpRender400);
    if render && checkpoint.is_file() {
        rows.push(bench_ngp_render_400(
            &checkpoint,
            &lego.data_dir,
            lego.views,
            machine,
            device,
        )?);
    } else if render {
        nerf::core::term::note(&format!(
            "skipping the 400x400 hash-grid benchmark: checkpoint {} not found",
            checkpoint.display()
        ));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flop_count_of_the_shipped_field() {
        let flops = NgpFlops::of_config(&Config::load("nerf_lego_ngp", &[]).unwrap()).unwrap();
        assert_eq!(flops.forward_per_sample, 17408.0);
        assert_eq!(flops.forward_per_ray, 2048.0);
        assert_eq!(flops.train_per_sample(), 3.0 * 17408.0);
        // 16 levels × 8 corners read forward; training adds into as many backward.
        assert_eq!(flops.table_rows_per_sample, 128.0);
        assert_eq!(flops.train_table_rows_per_sample(), 256.0);
        assert!(NgpFlops::of_config(&Config::load("nerf_lego", &[]).unwrap()).is_err());
    }

    #[test]
    fn throughput_fractions_are_of_the_measured_rates() {
        let rates = GemmRates {
            mlp: 100.0,
            square: 200.0,
        };
        let t = GemmRates::throughput(Some(&rates), 50.0);
        assert_eq!(t.fraction_of_mlp_gemm, Some(0.5));
        assert_eq!(t.fraction_of_square_gemm, Some(0.25));
        assert!(t.describe().contains("50.0% of the MLP-shaped gemm"));
        assert_eq!(GemmRates::throughput(None, 50.0).fraction_of_mlp_gemm, None);
        let (rows, fraction) = table_traffic(120e6, Some(300e6));
        assert_eq!((rows, fraction), (Some(120e6), Some(0.4)));
        let row = Throughput {
            table_rows_per_second: rows,
            fraction_of_random_reads: fraction,
            ..t
        };
        assert!(
            row.describe()
                .contains("120.00M table rows/s = 40.0% of the random-read rate"),
            "{}",
            row.describe()
        );
        // Without the memory rows (or with a rate of 0): rows per second and no fraction.
        assert_eq!(table_traffic(120e6, None).1, None);
        assert_eq!(table_traffic(120e6, Some(0.0)).1, None);
    }
}
