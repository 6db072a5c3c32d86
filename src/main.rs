//! The `nerf` command line: parses arguments and calls the library.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use candle_core::Device;
use clap::{Parser, Subcommand};

use nerf::app::config::Config;
use nerf::app::jobs;
use nerf::app::scene::render_scene;

/// Prints `wrote <path>` for each file written.
fn print_written(paths: &[PathBuf]) {
    for p in paths {
        println!("wrote {}", p.display());
    }
}

/// Prints each line.
fn print_lines(lines: &[String]) {
    for l in lines {
        println!("{l}");
    }
}

/// mimalloc keeps freed segments for reuse: Candle allocates a fresh buffer of up to tens of
/// megabytes per op, and an allocator that returns each to the OS pays page faults on the next
/// op (`nerf::tune_allocator` does the same for glibc, for programs on the system allocator).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(
    name = "nerf",
    version,
    about = "Differentiable volume rendering and NeRF on Candle (pytorch3d conventions)"
)]
struct Cli {
    /// Fused CPU kernels where they exist, or the generic tensor ops everywhere.
    #[arg(long, global = true, value_enum, default_value = "fused")]
    kernels: KernelsArg,
    /// Where tensors live (cuda and metal need the binary built with that feature).
    #[arg(long, global = true, value_enum, default_value = "cpu")]
    device: DeviceArg,
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum KernelsArg {
    Fused,
    Generic,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum DeviceArg {
    Cpu,
    Cuda,
    Metal,
}

/// The device asked for, or an error saying how to get it.
fn device(arg: DeviceArg) -> Result<Device> {
    Ok(match arg {
        DeviceArg::Cpu => Device::Cpu,
        DeviceArg::Cuda => Device::new_cuda(0).map_err(|e| {
            anyhow::anyhow!(
                "--device cuda: {e} (build with `cargo build --release --features cuda`)"
            )
        })?,
        DeviceArg::Metal => Device::new_metal(0).map_err(|e| {
            anyhow::anyhow!(
                "--device metal: {e} (build with `cargo build --release --features metal`)"
            )
        })?,
    })
}

#[derive(Subcommand)]
enum Command {
    /// Run a config's job by its `type`, as the homework's main.py: render, render_nerf,
    /// train (fit an SDF volume to images) or train_nerf.
    Run(RunArgs),
    /// Render a scene's surround views and visualisations into an output directory.
    Render {
        /// Config name (configs/NAME.yaml or built-in) or path to a YAML file.
        #[arg(long, alias = "config-name")]
        config: String,
        /// Output directory.
        #[arg(long, default_value = "images")]
        out_dir: PathBuf,
        /// Also write color_{i:03}.npy (H,W,3) and depth_{i:03}.npy (H,W) float32 per frame.
        #[arg(long)]
        raw: bool,
        /// NeRF checkpoint to render (NeRF configs only; default: training.checkpoint_path,
        /// else checkpoints/nerf_lego.safetensors): a safetensors or PyTorch file, told apart
        /// by content, or a directory holding one.
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// Hydra-style overrides, e.g. sampler.n_pts_per_ray=32 data.image_size=[200,150].
        overrides: Vec<String>,
    },
    /// Train: a NeRF (type train_nerf; checkpoints and resume as the config's training
    /// section says), or fit an SDF volume's opt: True parameters to the images of
    /// data.cameras (type train, e.g. train_box).
    Train {
        /// Config name or path (e.g. nerf_lego, train_box).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Dataset directory (default: data.data_dir, else ../shared/data/<dataset_name>).
        #[arg(long)]
        data_dir: Option<PathBuf>,
        /// Stop after this many epochs in this run (a checkpoint is written; resume continues).
        #[arg(long, value_parser = at_least_one)]
        epochs: Option<usize>,
        /// Where training images and GIFs go.
        #[arg(long, default_value = "images")]
        out_dir: PathBuf,
        /// Hydra-style overrides, e.g. training.num_epochs=20.
        overrides: Vec<String>,
    },
    /// Write the training targets of a type: train config: each data.cameras camera's view
    /// of the config's SDF volume, as a float32 (H, W, 3) .npy at its `image` path (set the
    /// volume to recover with overrides, e.g. implicit_function.sdf.center.val=[0.25,0.25,0]).
    Targets {
        /// Config name or path (e.g. train_box).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Hydra-style overrides.
        overrides: Vec<String>,
    },
    /// PSNR of a trained NeRF over a dataset split at the config's image size.
    Eval(EvalArgs),
    /// Convert a PyTorch state dict of the homework's NeRF (.pth) into a checkpoint.
    ImportTorch {
        /// The .pth file (`torch.save(model.state_dict())`, or a dict holding it under
        /// model / model_state_dict / state_dict).
        pth: PathBuf,
        /// Config whose implicit_function describes the model's sizes.
        #[arg(long, alias = "config-name", default_value = "nerf_lego")]
        config: String,
        /// Where to write the safetensors checkpoint.
        #[arg(long, default_value = "checkpoints/imported.safetensors")]
        out: PathBuf,
        /// Hydra-style overrides.
        overrides: Vec<String>,
    },
    /// Time the main jobs and print a table (or JSON).
    Bench(BenchArgs),
    /// Measure error against run time (box, lego, training) and write a Markdown report with
    /// PNG plots.
    Report(ReportArgs),
}

/// The options of `nerf run`.
#[derive(clap::Args)]
struct RunArgs {
    /// Config name (configs/NAME.yaml or built-in, e.g. train_box) or path to a YAML file.
    #[arg(long, alias = "config-name")]
    config: String,
    /// Output directory for images.
    #[arg(long, default_value = "images")]
    out_dir: PathBuf,
    /// NeRF checkpoint to render (default: training.checkpoint_path, else
    /// checkpoints/nerf_lego.safetensors); a file of ours or PyTorch's, or a directory.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Dataset directory for train_nerf (default: data.data_dir, else
    /// ../shared/data/<dataset_name>).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Hydra-style overrides, e.g. training.num_epochs=100.
    overrides: Vec<String>,
}

/// The options of `nerf eval`.
#[derive(clap::Args)]
struct EvalArgs {
    /// Config name or path (e.g. lego).
    #[arg(long, alias = "config-name")]
    config: String,
    /// Which split to score.
    #[arg(long, value_enum, default_value = "test")]
    split: SplitArg,
    /// NeRF checkpoint to evaluate (default: training.checkpoint_path, else
    /// checkpoints/nerf_lego.safetensors): a safetensors or PyTorch file, or a directory.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Dataset directory (default: data.data_dir, else ../shared/data/<dataset_name>).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Write each predicted view as <frame>.png into this directory.
    #[arg(long)]
    save_images: Option<PathBuf>,
    /// Score only the first N views.
    #[arg(long, value_parser = at_least_one)]
    limit: Option<usize>,
    /// Print JSON instead of a summary.
    #[arg(long)]
    json: bool,
    /// Hydra-style overrides.
    overrides: Vec<String>,
}

/// The options of `nerf bench`.
#[derive(clap::Args)]
struct BenchArgs {
    /// Config of the SDF scene to time.
    #[arg(long, alias = "config-name", default_value = "box")]
    config: String,
    /// Repeats of the box render and the training step (the best is reported; the first
    /// training step is a cold one, so use at least 2); the untrained frame is rendered
    /// min(repeats, 2) times; the trained-NeRF rows render each view once and report the
    /// mean.
    #[arg(long, default_value_t = 3, value_parser = at_least_one)]
    repeats: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Trained NeRF to time dense against accelerated rendering (skipped when missing).
    #[arg(long, default_value = "checkpoints/nerf_lego.safetensors")]
    checkpoint: PathBuf,
    /// Lego dataset directory for the ground truth (default ../shared/data/lego).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Test views rendered for the trained-NeRF benchmark.
    #[arg(long, default_value_t = 5, value_parser = at_least_one)]
    views: usize,
    /// Hydra-style overrides for the SDF config (the NeRF rows use the built-in nerf_lego
    /// and lego configs, at the work of the PyTorch figures).
    overrides: Vec<String>,
}

/// The options of `nerf report`.
#[derive(clap::Args)]
struct ReportArgs {
    /// Output directory (report.md, report.json, plots).
    #[arg(long, default_value = "reports")]
    out_dir: PathBuf,
    /// CI-sized run: small images, fewer sample counts and views, one repeat.
    #[arg(long)]
    quick: bool,
    /// Trained NeRF for the lego section (skipped with a note when missing).
    #[arg(long, default_value = "checkpoints/nerf_lego.safetensors")]
    checkpoint: PathBuf,
    /// Lego dataset directory (default ../shared/data/lego).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Test views for the lego section (default 5; 2 with --quick).
    #[arg(long, value_parser = at_least_one)]
    views: Option<usize>,
    /// Training logs to plot (default: the checkpoint's .log.jsonl and
    /// checkpoints/homework/nerf_lego.log.jsonl).
    #[arg(long = "log")]
    logs: Vec<PathBuf>,
}

/// A count of at least 1, for clap.
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum SplitArg {
    Train,
    Val,
    Test,
}

impl From<SplitArg> for nerf::io::dataset::Split {
    fn from(s: SplitArg) -> Self {
        match s {
            SplitArg::Train => Self::Train,
            SplitArg::Val => Self::Val,
            SplitArg::Test => Self::Test,
        }
    }
}

/// `nerf run`: the job of the config's `type`.
fn run_config(a: RunArgs, device: &Device) -> Result<()> {
    let loaded = Config::load(&a.config, &a.overrides)?;
    match jobs::run_job(&loaded, &a.config)? {
        jobs::RunJob::Render => print_written(&render_scene(
            &loaded,
            a.checkpoint.as_deref(),
            &a.out_dir,
            false,
            device,
        )?),
        jobs::RunJob::Train(job) => {
            let nerf = jobs::NerfTrainOptions {
                data_dir: a.data_dir,
                epochs: None,
            };
            print_lines(&jobs::train(&loaded, job, &nerf, &a.out_dir, device)?)
        }
    }
    Ok(())
}

/// `nerf eval`.
fn eval(a: EvalArgs, device: &Device) -> Result<()> {
    let config = Config::load(&a.config, &a.overrides)?;
    let data_dir = jobs::data_dir_for(&config, a.data_dir);
    let report = nerf::app::evaluate::eval_nerf(
        &config,
        a.checkpoint.as_deref(),
        &data_dir,
        a.split.into(),
        a.save_images.as_deref(),
        a.limit,
        device,
    )?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("{}", report.summary());
    }
    Ok(())
}

/// `nerf bench`.
fn bench(a: BenchArgs, device: &Device) -> Result<()> {
    let config = Config::load(&a.config, &a.overrides)?;
    let lego = nerf::app::bench::LegoBench {
        checkpoint: a.checkpoint,
        data_dir: a
            .data_dir
            .unwrap_or_else(|| nerf::io::dataset::default_data_dir("lego")),
        views: a.views,
    };
    let report = nerf::app::bench::run_benchmarks(&config, a.repeats, Some(&lego), device)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", nerf::app::bench::format_table(&report));
    }
    Ok(())
}

/// `nerf report`.
fn report(a: ReportArgs, device: &Device) -> Result<()> {
    let training_logs = if a.logs.is_empty() {
        nerf::app::report::default_training_logs(&a.checkpoint)
    } else {
        a.logs
    };
    let options = nerf::app::report::ReportOptions {
        out_dir: a.out_dir,
        quick: a.quick,
        checkpoint: a.checkpoint,
        data_dir: a
            .data_dir
            .unwrap_or_else(|| nerf::io::dataset::default_data_dir("lego")),
        views: a.views,
        training_logs,
    };
    for p in nerf::app::report::write_report(&options, device)? {
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    nerf::kernels::set_kernel_choice(match cli.kernels {
        KernelsArg::Fused => nerf::kernels::KernelChoice::Fused,
        KernelsArg::Generic => nerf::kernels::KernelChoice::Generic,
    });
    let device = device(cli.device)?;
    match cli.command {
        Command::Run(a) => run_config(a, &device)?,
        Command::Render {
            config,
            out_dir,
            raw,
            checkpoint,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            print_written(&render_scene(
                &config,
                checkpoint.as_deref(),
                &out_dir,
                raw,
                &device,
            )?);
        }
        Command::Train {
            config,
            data_dir,
            epochs,
            out_dir,
            overrides,
        } => {
            let loaded = Config::load(&config, &overrides)?;
            let job = jobs::train_job(&loaded, &config)?;
            let nerf = jobs::NerfTrainOptions { data_dir, epochs };
            print_lines(&jobs::train(&loaded, job, &nerf, &out_dir, &device)?);
        }
        Command::Targets { config, overrides } => {
            let config = Config::load(&config, &overrides)?;
            print_written(&nerf::app::train_box::write_targets(&config, &device)?);
        }
        Command::Eval(a) => eval(a, &device)?,
        Command::ImportTorch {
            pth,
            config,
            out,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            let n = nerf::io::torch::import_torch(&pth, &config.nerf_params()?, &out)?;
            eprintln!(
                "wrote {} ({n} parameters from {})",
                out.display(),
                pth.display()
            );
        }
        Command::Bench(a) => bench(a, &device)?,
        Command::Report(a) => report(a, &device)?,
    }
    Ok(())
}

fn main() -> ExitCode {
    // Keep freed mimalloc segments instead of returning them to the OS after 10 ms: training
    // allocates and frees large activations every op (measured when they were 64 MB: 3.8 →
    // 1.9 s per step).
    // SAFETY: sets a process-wide allocator option before any worker threads start.
    // The binding does not export these two enum values of mimalloc v2's `mi_option_e`.
    const MI_OPTION_ARENA_EAGER_COMMIT: libmimalloc_sys::mi_option_t = 4;
    const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;
    unsafe {
        libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1);
        libmimalloc_sys::mi_option_set(MI_OPTION_ARENA_EAGER_COMMIT, 1);
    }
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the chain of causes joined by ": ", each cut to its first line (Candle
            // appends a backtrace to its errors' text when RUST_BACKTRACE is set).
            let causes: Vec<String> = e
                .chain()
                .map(|c| c.to_string().lines().next().unwrap_or("").to_string())
                .collect();
            eprintln!("error: {}", causes.join(": "));
            ExitCode::FAILURE
        }
    }
}
