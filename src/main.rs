//! The `nerf` command line: parses arguments and calls the library.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Result;
use candle_core::Device;
use clap::{Args, Parser, Subcommand};

use nerf::app::config::Config;
use nerf::app::jobs;

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
    /// Render a scene's surround views and visualisations (or a camera path) into an output
    /// directory.
    Render(RenderArgs),
    /// Train: a NeRF (type train_nerf; checkpoints and resume as the config's training
    /// section says), or fit an SDF volume's opt: True parameters to the images of
    /// data.cameras (type train, e.g. train_box).
    Train(TrainArgs),
    /// Write a training config's target images (the `.npy` of each data.cameras entry),
    /// rendered from its SDF volume with every parameter at its initial value.
    Targets {
        /// Config name or path (e.g. train_box).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Hydra-style overrides.
        overrides: Vec<String>,
    },
    /// PSNR and SSIM of a trained NeRF over a dataset split at the config's image size.
    Eval(EvalArgs),
    /// Convert a PyTorch state dict of the homework's NeRF (.pth) into a checkpoint.
    ImportTorch(ImportTorchArgs),
    /// Time the main jobs and print a table (or JSON).
    Bench(BenchArgs),
    /// Measure error against run time (box, lego, training) and write a Markdown report with
    /// PNG plots.
    Report(ReportArgs),
    /// Serve a web page that shows the scene live (drag to orbit, wheel to zoom, shift-drag to
    /// pan) and the HTTP API it uses: GET
    /// /render.png?eye=x,y,z&at=x,y,z&up=x,y,z&focal=F&width=W&height=H.
    View(ViewArgs),
    /// Take a scene out as files: a coloured mesh, a point cloud, or depth maps.
    Export {
        #[command(subcommand)]
        what: ExportCommand,
    },
}

/// Run a config's job by its `type`.
#[derive(Args)]
struct RunArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file with a `type`.
    #[arg(long, alias = "config-name")]
    config: String,
    /// Output directory for images.
    #[arg(long, default_value = "images")]
    out_dir: PathBuf,
    /// Checkpoint to render (render_nerf configs; the same default as `nerf render`).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Dataset directory (train_nerf configs).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Hydra-style overrides.
    overrides: Vec<String>,
}

/// Render a scene's surround views and visualisations into an output directory.
#[derive(Args)]
struct RenderArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file.
    #[arg(long, alias = "config-name")]
    config: String,
    /// Output directory.
    #[arg(long, default_value = "images")]
    out_dir: PathBuf,
    /// Also write color_{i:03}.npy (H,W,3) and depth_{i:03}.npy (H,W) float32 per frame.
    #[arg(long)]
    raw: bool,
    /// Checkpoint to use (default: the config's training.checkpoint_path — a file, or a
    /// directory holding nerf_<dataset>.safetensors — else the shipped
    /// checkpoints/nerf_lego.safetensors).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Render this nerfstudio camera_path.json instead of the surround views:
    /// frame_NNNN.png, camera_path.gif and, when ffmpeg is on PATH, camera_path.mp4.
    #[arg(long, conflicts_with = "raw")]
    camera_path: Option<PathBuf>,
    /// Hydra-style overrides, e.g. sampler.n_pts_per_ray=32 data.image_size=[200,150].
    overrides: Vec<String>,
}

/// Train a NeRF (checkpoints and resume as the config's training section says).
#[derive(Args)]
struct TrainArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g. nerf_lego).
    #[arg(long, alias = "config-name")]
    config: String,
    /// Dataset directory (default: data.data_dir, else ../shared/data/<dataset_name>).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Stop after this many epochs in this run (a checkpoint is written; resume continues).
    #[arg(long, value_parser = at_least_one)]
    epochs: Option<usize>,
    /// Stop after this many minutes of training in this run (a checkpoint is written; resume
    /// continues exactly).
    #[arg(long, value_parser = positive_minutes)]
    minutes: Option<f64>,
    /// Where training GIFs go.
    #[arg(long, default_value = "images")]
    out_dir: PathBuf,
    /// With `training.resume: False`, replace an existing checkpoint and its log (without it,
    /// such a run is refused).
    #[arg(long)]
    overwrite: bool,
    /// Hydra-style overrides, e.g. training.num_epochs=20.
    overrides: Vec<String>,
}

/// PSNR and SSIM of a trained NeRF over a dataset split at the config's image size.
#[derive(Args)]
struct EvalArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g. lego).
    #[arg(long, alias = "config-name")]
    config: String,
    /// Which split to score.
    #[arg(long, value_enum, default_value = "test")]
    split: SplitArg,
    /// Checkpoint to use (default: the config's training.checkpoint_path — a file, or a
    /// directory holding nerf_<dataset>.safetensors — else the shipped
    /// checkpoints/nerf_lego.safetensors).
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
    /// Composite ground truth and prediction on white (the NeRF papers' protocol) instead of
    /// black (the homework's); the same as `renderer.white_background=True`.
    #[arg(long)]
    white: bool,
    /// Hydra-style overrides.
    overrides: Vec<String>,
}

/// Convert a PyTorch state dict of the homework's NeRF (.pth) into a checkpoint.
#[derive(Args)]
struct ImportTorchArgs {
    /// The .pth file (`torch.save(model.state_dict())`, or a dict holding it under
    /// model / model_state_dict / state_dict).
    pth: PathBuf,
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file: its
    /// implicit_function gives the model's sizes (e.g. nerf_lego).
    #[arg(long, alias = "config-name")]
    config: String,
    /// Where to write the safetensors checkpoint.
    #[arg(long, default_value = "checkpoints/imported.safetensors")]
    out: PathBuf,
    /// Hydra-style overrides.
    overrides: Vec<String>,
}

/// Time the main jobs and print a table (or JSON).
#[derive(Args)]
struct BenchArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file: the SDF scene to
    /// time (e.g. box; the NeRF rows use the built-in nerf_lego and lego configs).
    #[arg(long, alias = "config-name")]
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
    /// Checkpoint of the trained-NeRF rows, rendered with the built-in lego config (default: the
    /// shipped checkpoints/nerf_lego.safetensors; the rows are skipped when it is missing).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Dataset directory (default: data.data_dir of the lego config, else ../shared/data/lego).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Test views rendered for the trained-NeRF benchmark.
    #[arg(long, default_value_t = 5, value_parser = at_least_one)]
    views: usize,
    /// Hydra-style overrides for the SDF config (the NeRF rows use the built-in nerf_lego
    /// and lego configs, at the work of the PyTorch figures).
    overrides: Vec<String>,
}

/// Measure error against run time (box, lego, training) and write a Markdown report with
/// PNG plots.
#[derive(Args)]
struct ReportArgs {
    /// Output directory (report.md, report.json, plots).
    #[arg(long, default_value = "reports")]
    out_dir: PathBuf,
    /// CI-sized run: small images, fewer sample counts and views, one repeat.
    #[arg(long)]
    quick: bool,
    /// Checkpoint of the lego section, rendered with the built-in lego config (default: the
    /// shipped checkpoints/nerf_lego.safetensors). A missing checkpoint or dataset is an error
    /// unless --no-lego is given.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Leave out the lego section (no checkpoint or dataset needed).
    #[arg(long, conflicts_with_all = ["checkpoint", "data_dir", "views"])]
    no_lego: bool,
    /// Dataset directory (default: data.data_dir of the lego config, else ../shared/data/lego).
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

/// Serve the live viewer.
#[derive(Args)]
struct ViewArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g. lego, box).
    #[arg(long, alias = "config-name")]
    config: String,
    /// Checkpoint to use (default: the config's training.checkpoint_path — a file, or a
    /// directory holding nerf_<dataset>.safetensors — else the shipped
    /// checkpoints/nerf_lego.safetensors).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Port to listen on (0 picks a free one; the address is printed).
    #[arg(long, default_value_t = 7007)]
    port: u16,
    /// Address to bind; the default serves this machine only. Requests are answered only when
    /// their Host header names the viewer: loopback names when bound to loopback, else the
    /// bound address and this value.
    #[arg(long, default_value = "127.0.0.1")]
    host: String,
    /// Milliseconds a connection may take to send a request head, from its opening or its
    /// previous response (so also the idle keep-alive time); tests shorten it.
    #[arg(long, hide = true, default_value_t = 10_000,
          value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    header_timeout_ms: u64,
    /// Hydra-style overrides (sampler, renderer, cameras and data.image_size set the
    /// defaults of /render.png).
    overrides: Vec<String>,
}

#[derive(Subcommand)]
enum ExportCommand {
    /// Marching cubes on the density, vertex colours from the field: a binary PLY mesh.
    Mesh {
        /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g. lego, box).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Checkpoint to use (default: the config's training.checkpoint_path — a file, or a
        /// directory holding nerf_<dataset>.safetensors — else the shipped
        /// checkpoints/nerf_lego.safetensors).
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// Marching-cubes cells per side of the box (the NeRF's occupancy-grid box, or a box
        /// around the SDF's shape), 1 to 512.
        #[arg(long, default_value_t = 256)]
        resolution: usize,
        /// Density at the surface: NeRF sigma (default 10), or the homework's SDF density
        /// between 0 and alpha (default alpha/2, the SDF's zero level).
        #[arg(long)]
        threshold: Option<f64>,
        /// The PLY file to write.
        #[arg(long)]
        out: PathBuf,
        /// Hydra-style overrides.
        overrides: Vec<String>,
    },
    /// The expected-depth points of the dataset's views (opacity above 0.5) with their
    /// colours: a binary PLY point cloud.
    Points {
        /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g. lego).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Checkpoint to use (default: the config's training.checkpoint_path — a file, or a
        /// directory holding nerf_<dataset>.safetensors — else the shipped
        /// checkpoints/nerf_lego.safetensors).
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// Dataset split whose views are rendered (NeRF; SDF scenes use the surround cameras).
        #[arg(long, value_enum, default_value = "train")]
        split: SplitArg,
        /// Dataset directory (default: data.data_dir, else ../shared/data/<dataset_name>).
        #[arg(long)]
        data_dir: Option<PathBuf>,
        /// Only the first N views.
        #[arg(long, value_parser = at_least_one)]
        limit: Option<usize>,
        /// The PLY file to write.
        #[arg(long)]
        out: PathBuf,
        /// Hydra-style overrides (data.image_size sets the rendering size).
        overrides: Vec<String>,
    },
    /// The model of a training checkpoint without the optimiser's state (an NGP's hash table
    /// as f16): what rendering and evaluation need, a fraction of the size.
    Model {
        /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g.
        /// nerf_lego_ngp).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Checkpoint to read (default: the config's training.checkpoint_path, else the
        /// shipped checkpoints/nerf_lego.safetensors).
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// The safetensors file to write.
        #[arg(long)]
        out: PathBuf,
        /// Hydra-style overrides.
        overrides: Vec<String>,
    },
    /// A depth .npy (H, W) and a viridis PNG for each view of a split.
    Depth {
        /// Config name (configs/NAME.yaml or built-in) or path to a YAML file (e.g. lego).
        #[arg(long, alias = "config-name")]
        config: String,
        /// Checkpoint to use (default: the config's training.checkpoint_path — a file, or a
        /// directory holding nerf_<dataset>.safetensors — else the shipped
        /// checkpoints/nerf_lego.safetensors).
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// Dataset split (NeRF; SDF scenes use the surround cameras).
        #[arg(long, value_enum, default_value = "test")]
        split: SplitArg,
        /// Dataset directory (default: data.data_dir, else ../shared/data/<dataset_name>).
        #[arg(long)]
        data_dir: Option<PathBuf>,
        /// Only the first N views.
        #[arg(long, value_parser = at_least_one)]
        limit: Option<usize>,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Hydra-style overrides.
        overrides: Vec<String>,
    },
}

/// `nerf view`: serves until killed.
fn cmd_view(a: ViewArgs, device: &Device) -> Result<()> {
    let config = Config::load(&a.config, &a.overrides)?;
    let scene = nerf::app::scene::load_scene_field(&config, a.checkpoint.as_deref(), device)?;
    let options = nerf::app::view::ViewOptions {
        host: a.host,
        port: a.port,
        header_timeout: std::time::Duration::from_millis(a.header_timeout_ms),
    };
    nerf::app::view::serve(&config, &a.config, scene, &options, device)
}

/// `nerf export …`.
/// `nerf export mesh`: runs the export and says what it wrote.
fn cmd_export_mesh(
    config: &Config,
    checkpoint: Option<&Path>,
    options: &nerf::app::export::MeshOptions,
    device: &Device,
) -> Result<()> {
    let m = nerf::app::export::export_mesh(config, checkpoint, options, device)?;
    say(&format!(
        "wrote {} ({} vertices, {} triangles, threshold {}, {:.1} s)",
        options.out.display(),
        m.vertices,
        m.faces,
        m.threshold,
        m.seconds
    ))
}

/// `nerf export model`: runs the export and says what it wrote.
fn cmd_export_model(
    config: &Config,
    checkpoint: Option<&Path>,
    out: &Path,
    device: &Device,
) -> Result<()> {
    let e = nerf::app::export_model::export_model(config, checkpoint, out, device)?;
    say(&format!(
        "wrote {} ({} tensors, {:.1} MB; largest f16 rounding of the table {:.1e})",
        out.display(),
        e.tensors,
        e.bytes as f64 / 1e6,
        e.table_rounding
    ))
}

fn cmd_export(what: ExportCommand, device: &Device) -> Result<()> {
    use nerf::app::export::{export_depth, export_points, MeshOptions, ViewSelection};
    let views = |config: &Config, split: SplitArg, data_dir, limit| ViewSelection {
        split: split.into(),
        data_dir: jobs::data_dir_for(config, data_dir),
        limit,
    };
    match what {
        ExportCommand::Mesh {
            config,
            checkpoint,
            resolution,
            threshold,
            out,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            let options = MeshOptions {
                resolution,
                threshold,
                out,
            };
            cmd_export_mesh(&config, checkpoint.as_deref(), &options, device)?;
        }
        ExportCommand::Points {
            config,
            checkpoint,
            split,
            data_dir,
            limit,
            out,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            let views = views(&config, split, data_dir, limit);
            let n = export_points(&config, checkpoint.as_deref(), &views, &out, device)?;
            say(&format!("wrote {} ({n} points)", out.display()))?;
        }
        ExportCommand::Model {
            config,
            checkpoint,
            out,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            cmd_export_model(&config, checkpoint.as_deref(), &out, device)?;
        }
        ExportCommand::Depth {
            config,
            checkpoint,
            split,
            data_dir,
            limit,
            out,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            let views = views(&config, split, data_dir, limit);
            let written = export_depth(&config, checkpoint.as_deref(), &views, &out, device)?;
            say(&format!(
                "wrote {} files into {}",
                written.len(),
                out.display()
            ))?;
        }
    }
    Ok(())
}

/// A count of at least 1, for clap.
fn positive_minutes(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(m) if m.is_finite() && m > 0.0 => Ok(m),
        Ok(_) => Err("must be a positive number of minutes".into()),
        Err(e) => Err(e.to_string()),
    }
}

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

/// Writing to stdout failed (a closed pipe, a full disk).
#[derive(Debug)]
struct StdoutError(std::io::Error);

impl std::fmt::Display for StdoutError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "cannot write to stdout: {}", self.0)
    }
}

impl std::error::Error for StdoutError {}

/// Writes `line` and a newline to stdout; `println!` would panic when that fails.
fn say(line: &str) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")
        .and_then(|()| out.flush())
        .map_err(|e| anyhow::Error::new(StdoutError(e)))
}

/// Exit code for a closed stdout pipe: 128 + SIGPIPE, as a shell reports a process that
/// SIGPIPE ended, so `nerf ... | head` ends quietly and scripts can still tell.
const BROKEN_PIPE_EXIT: u8 = 141;

fn run(cli: Cli) -> Result<()> {
    nerf::kernels::set_kernel_choice(match cli.kernels {
        KernelsArg::Fused => nerf::kernels::KernelChoice::Fused,
        KernelsArg::Generic => nerf::kernels::KernelChoice::Generic,
    });
    let device = device(cli.device)?;
    match cli.command {
        Command::Run(args) => cmd_run(args, &device),
        Command::Render(args) => cmd_render(args, &device),
        Command::Train(args) => cmd_train(args, &device),
        Command::Targets { config, overrides } => {
            let config = Config::load(&config, &overrides)?;
            for p in nerf::app::train_box::write_targets(&config, &device)? {
                say(&format!("wrote {}", p.display()))?;
            }
            Ok(())
        }
        Command::Eval(args) => cmd_eval(args, &device),
        Command::ImportTorch(args) => cmd_import_torch(args, &device),
        Command::Bench(args) => cmd_bench(args, &device),
        Command::Report(args) => cmd_report(args, &device),
        Command::View(args) => cmd_view(args, &device),
        Command::Export { what } => cmd_export(what, &device),
    }
}

fn cmd_render(args: RenderArgs, device: &Device) -> Result<()> {
    let RenderArgs {
        config,
        out_dir,
        raw,
        checkpoint,
        camera_path,
        overrides,
    } = args;
    let config = Config::load(&config, &overrides)?;
    let written = match &camera_path {
        Some(path) => nerf::app::camera_path::render_camera_path(
            &config,
            checkpoint.as_deref(),
            path,
            &out_dir,
            device,
        )?,
        None => {
            nerf::app::scene::render_scene(&config, checkpoint.as_deref(), &out_dir, raw, device)?
        }
    };
    for p in written {
        say(&format!("wrote {}", p.display()))?;
    }
    Ok(())
}

fn cmd_train(args: TrainArgs, device: &Device) -> Result<()> {
    let TrainArgs {
        config,
        data_dir,
        epochs,
        minutes,
        out_dir,
        overwrite,
        overrides,
    } = args;
    let loaded = Config::load(&config, &overrides)?;
    let job = jobs::train_job(&loaded, &config)?;
    let options = jobs::NerfTrainOptions {
        data_dir,
        epochs,
        minutes,
        overwrite,
    };
    train_and_say(&loaded, job, &options, &out_dir, device)
}

/// Runs a training job, stopping after the current step on SIGINT/SIGTERM, and prints what it
/// did (or, stopped, how to resume).
fn train_and_say(
    config: &Config,
    job: jobs::TrainJob,
    options: &jobs::NerfTrainOptions,
    out_dir: &std::path::Path,
    device: &Device,
) -> Result<()> {
    let stop = match job {
        jobs::TrainJob::Nerf => Some(nerf::app::train::stop_on_signal()?),
        jobs::TrainJob::Sdf => None,
    };
    match jobs::train(config, job, options, out_dir, stop, device)? {
        jobs::TrainOutcome::Done(lines) => lines.iter().try_for_each(|l| say(l)),
        jobs::TrainOutcome::Stopped { info, checkpoint } => {
            Err(anyhow::Error::new(Stopped(format!(
                "stopped at epoch {} step {}; checkpoint {}; resume with: {}",
                info.epoch,
                info.adam_step,
                checkpoint.display(),
                resume_command(config.training()?.resume)
            ))))
        }
    }
}

fn cmd_run(args: RunArgs, device: &Device) -> Result<()> {
    let RunArgs {
        config,
        out_dir,
        checkpoint,
        data_dir,
        overrides,
    } = args;
    let loaded = Config::load(&config, &overrides)?;
    match jobs::run_job(&loaded, &config)? {
        jobs::RunJob::Render => {
            let written = nerf::app::scene::render_scene(
                &loaded,
                checkpoint.as_deref(),
                &out_dir,
                false,
                device,
            )?;
            written
                .iter()
                .try_for_each(|p| say(&format!("wrote {}", p.display())))
        }
        jobs::RunJob::Train(job) => {
            let options = jobs::NerfTrainOptions {
                data_dir,
                ..Default::default()
            };
            train_and_say(&loaded, job, &options, &out_dir, device)
        }
    }
}

/// The command line that resumes this training run: the same arguments without
/// `--overwrite`, and with `training.resume=True` when the config does not resume.
fn resume_command(config_resumes: bool) -> String {
    let mut args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--overwrite")
        .collect();
    if !config_resumes {
        args.push("training.resume=True".into());
    }
    std::iter::once("nerf".to_string())
        .chain(args.iter().map(|a| {
            if a.contains(|c: char| c.is_whitespace() || "[]'\"$".contains(c)) {
                format!("'{a}'")
            } else {
                a.clone()
            }
        }))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Training was stopped by a signal; the message says where and how to resume.
#[derive(Debug)]
struct Stopped(String);

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Stopped {}

/// Exit code of a run stopped by SIGINT or SIGTERM (128 + SIGINT, as shells report it).
const STOPPED_EXIT: u8 = 130;

fn cmd_eval(args: EvalArgs, device: &Device) -> Result<()> {
    let EvalArgs {
        config,
        split,
        checkpoint,
        data_dir,
        save_images,
        limit,
        json,
        white,
        overrides,
    } = args;
    let mut config = Config::load(&config, &overrides)?;
    if white {
        config.renderer.white_background = true;
    }
    let data_dir = jobs::data_dir_for(&config, data_dir);
    let report = nerf::app::evaluate::eval_nerf(
        &config,
        checkpoint.as_deref(),
        &data_dir,
        split.into(),
        save_images.as_deref(),
        limit,
        device,
    )?;
    if json {
        say(&serde_json::to_string_pretty(&report)?)?;
    } else {
        say(&report.summary())?;
    }
    Ok(())
}

fn cmd_import_torch(args: ImportTorchArgs, _device: &Device) -> Result<()> {
    let ImportTorchArgs {
        pth,
        config,
        out,
        overrides,
    } = args;
    let config = Config::load(&config, &overrides)?;
    let n = nerf::io::torch::import_torch(&pth, &config.field_spec()?.parameter_shapes()?, &out)?;
    nerf::core::term::note(&format!(
        "wrote {} ({n} parameters from {})",
        out.display(),
        pth.display()
    ));
    Ok(())
}

fn cmd_bench(args: BenchArgs, device: &Device) -> Result<()> {
    let BenchArgs {
        config,
        repeats,
        json,
        checkpoint,
        data_dir,
        views,
        overrides,
    } = args;
    let config = Config::load(&config, &overrides)?;
    let lego_config = Config::load("lego", &[])?;
    let lego = nerf::app::bench::LegoBench {
        checkpoint: lego_config.checkpoint(checkpoint.as_deref()),
        data_dir: jobs::data_dir_for(&lego_config, data_dir),
        views,
    };
    let report = nerf::app::bench::run_benchmarks(&config, repeats, Some(&lego), device)?;
    if json {
        say(&serde_json::to_string_pretty(&report)?)?;
    } else {
        say(nerf::app::bench::format_table(&report).trim_end())?;
    }
    Ok(())
}

fn cmd_report(args: ReportArgs, device: &Device) -> Result<()> {
    let ReportArgs {
        out_dir,
        quick,
        checkpoint,
        data_dir,
        views,
        logs,
        no_lego,
    } = args;
    let lego_config = Config::load("lego", &[])?;
    let checkpoint = lego_config.checkpoint(checkpoint.as_deref());
    let training_logs = if logs.is_empty() {
        nerf::app::report::default_training_logs(&checkpoint)
    } else {
        logs
    };
    let options = nerf::app::report::ReportOptions {
        out_dir,
        quick,
        checkpoint,
        data_dir: jobs::data_dir_for(&lego_config, data_dir),
        views,
        training_logs,
        ngp_checkpoint: Some(nerf::app::runtime::SHIPPED_NGP_CHECKPOINT.into()),
        lego: !no_lego,
    };
    for p in nerf::app::report::write_report(&options, device)? {
        say(&format!("wrote {}", p.display()))?;
    }
    Ok(())
}

fn main() -> ExitCode {
    nerf::app::messages::print_library_messages();
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
            if let Some(Stopped(message)) = e.downcast_ref::<Stopped>() {
                nerf::core::term::note(message);
                return ExitCode::from(STOPPED_EXIT);
            }
            if let Some(StdoutError(io)) = e.downcast_ref::<StdoutError>() {
                if io.kind() == std::io::ErrorKind::BrokenPipe {
                    return ExitCode::from(BROKEN_PIPE_EXIT);
                }
            }
            // One line: the chain of causes joined by ": ", each cut to its first line (Candle
            // appends a backtrace to its errors' text when RUST_BACKTRACE is set).
            let causes: Vec<String> = e
                .chain()
                .map(|c| c.to_string().lines().next().unwrap_or("").to_string())
                .collect();
            nerf::core::term::note(&format!("error: {}", causes.join(": ")));
            ExitCode::FAILURE
        }
    }
}
