//! The `nerf` command line's arguments (clap), parsed without running anything: tests parse
//! with [`Cli::try_parse_from`]. The options several subcommands take are defined once, as
//! flattened groups, so each means the same and reads the same everywhere: [`ConfigArgs`]
//! (`--config` / `--config-name` and the overrides), [`CheckpointArg`] (`--checkpoint`),
//! [`DataDirArg`] (`--data-dir`), [`OutDirArg`] (`--out-dir`) and [`TrainingArgs`]
//! (`--epochs`, `--minutes`, `--overwrite`). What each subcommand does with them is in
//! [`crate::commands`].
// The doc comments below are clap's help text, written for a terminal: `[200,150]` and
// `<frame>` there are what a user types, not rustdoc links or HTML.
#![allow(rustdoc::broken_intra_doc_links, rustdoc::invalid_html_tags)]

use std::path::PathBuf;

use anyhow::Result;
use candle_core::Device;
use clap::{Args, Parser, Subcommand, ValueEnum};

/// `nerf`: the global options and a subcommand.
#[derive(Parser, Debug)]
#[command(
    name = "nerf",
    version,
    about = "Differentiable volume rendering and NeRF on Candle (pytorch3d conventions)"
)]
pub struct Cli {
    /// Fused CPU kernels where they exist, or the generic tensor ops everywhere.
    #[arg(long, global = true, value_enum, default_value = "fused")]
    pub kernels: KernelsArg,
    /// Where tensors live (cuda and metal need the binary built with that feature).
    #[arg(long, global = true, value_enum, default_value = "cpu")]
    pub device: DeviceArg,
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// `--kernels`.
#[allow(missing_docs)] // each value is what the option's help says
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum KernelsArg {
    Fused,
    Generic,
}

impl From<KernelsArg> for nerf::kernels::KernelChoice {
    fn from(k: KernelsArg) -> Self {
        match k {
            KernelsArg::Fused => Self::Fused,
            KernelsArg::Generic => Self::Generic,
        }
    }
}

/// `--device`.
#[allow(missing_docs)] // each value is what the option's help says
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum DeviceArg {
    Cpu,
    Cuda,
    Metal,
}

impl DeviceArg {
    /// The device asked for, or an error saying how to get it.
    pub fn open(self) -> Result<Device> {
        Ok(match self {
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
}

/// The subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
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
    Targets(TargetsArgs),
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
    /// Photos to a trainable capture: copies them to OUT/images, runs COLMAP (feature
    /// extraction, matching, mapping; logs in OUT/colmap) and writes OUT/transforms.json
    /// (nerfstudio's format) for `nerf train --config nerf_scene --data-dir OUT`.
    Process(ProcessArgs),
    /// Take a scene out as files: a coloured mesh, a point cloud, or depth maps.
    Export {
        /// What to export.
        #[command(subcommand)]
        what: ExportCommand,
    },
}

/// `--config` (also spelt `--config-name`) and the overrides, for every subcommand that
/// loads a config.
#[derive(Args, Debug, Clone)]
pub struct ConfigArgs {
    /// Config name (configs/NAME.yaml or built-in) or path to a YAML file; also spelt
    /// --config-name, as the homework's Hydra command line does.
    #[arg(long, visible_alias = "config-name")]
    pub config: String,
    /// Hydra-style overrides, applied in order after the config is read, e.g.
    /// sampler.n_pts_per_ray=32 data.image_size=[200,150] (+key=value is accepted).
    pub overrides: Vec<String>,
}

impl ConfigArgs {
    /// The config `--config` names, with the overrides applied.
    pub fn load(&self) -> Result<nerf::config::Config> {
        Ok(nerf::config::Config::load(&self.config, &self.overrides)?)
    }
}

/// `--checkpoint`, for every subcommand that reads (or, training, writes) a NeRF checkpoint.
#[derive(Args, Debug, Clone, Default)]
pub struct CheckpointArg {
    /// NeRF checkpoint: a file, or a directory holding nerf_<dataset_name>.safetensors or else
    /// exactly one checkpoint file (default: the config's training.checkpoint_path, else the
    /// shipped checkpoints/nerf_lego.safetensors).
    ///
    /// A file is read by its content: ours (safetensors) or PyTorch's (torch.save). A
    /// directory holding several checkpoints and no nerf_<dataset_name>.safetensors is an
    /// error naming them. bench and report render it with the built-in lego config (so the
    /// default is that config's). Training (train, or run of a train_nerf config) takes it as
    /// the override training.checkpoint_path=PATH: the checkpoint resumed from and written
    /// to, where a new path with an extension is the file to write and one without is a
    /// directory to create; training never falls back to the shipped model.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
}

/// `--data-dir`, for every subcommand that reads a dataset.
#[derive(Args, Debug, Clone, Default)]
pub struct DataDirArg {
    /// Dataset directory (default: the config's data.data_dir, else
    /// ../shared/data/<dataset_name>; bench and report: of the built-in lego config).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
}

/// `--out-dir` for the images of rendering and training.
#[derive(Args, Debug, Clone)]
pub struct OutDirArg {
    /// Output directory for images (renders; training's previews and GIFs).
    #[arg(long, default_value = "images")]
    pub out_dir: PathBuf,
}

/// How long this training run goes, and whether it may replace an earlier one: `nerf train`
/// and `nerf run` of a training config.
#[derive(Args, Debug, Clone, Default)]
pub struct TrainingArgs {
    /// Stop after this many epochs in this run (a checkpoint is written; resume continues).
    /// NeRF training only.
    #[arg(long, value_parser = at_least_one)]
    pub epochs: Option<usize>,
    /// Stop after this many minutes of training in this run (a checkpoint is written; resume
    /// continues exactly). NeRF training only.
    #[arg(long, value_parser = positive_minutes)]
    pub minutes: Option<f64>,
    /// With `training.resume: False`, replace an existing checkpoint and its log (without it,
    /// such a run is refused). NeRF training only.
    #[arg(long)]
    pub overwrite: bool,
}

/// `nerf run`: a config's job by its `type`.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// The config and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The images' directory.
    #[command(flatten)]
    pub out: OutDirArg,
    /// The checkpoint (render_nerf and train_nerf configs).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// The dataset (train_nerf configs).
    #[command(flatten)]
    pub data: DataDirArg,
    /// The run's limits (train_nerf configs).
    #[command(flatten)]
    pub training: TrainingArgs,
}

/// `nerf render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// The config and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The images' directory.
    #[command(flatten)]
    pub out: OutDirArg,
    /// Also write color_{i:03}.npy (H,W,3) and depth_{i:03}.npy (H,W) float32 per frame.
    #[arg(long)]
    pub raw: bool,
    /// The checkpoint (NeRF configs).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// Render this nerfstudio camera_path.json instead of the surround views:
    /// frame_NNNN.png, camera_path.gif and, when ffmpeg is on PATH, camera_path.mp4.
    #[arg(long, conflicts_with = "raw")]
    pub camera_path: Option<PathBuf>,
}

/// `nerf train`.
#[derive(Args, Debug)]
pub struct TrainArgs {
    /// The config and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The dataset (NeRF training).
    #[command(flatten)]
    pub data: DataDirArg,
    /// The run's limits.
    #[command(flatten)]
    pub training: TrainingArgs,
    /// The checkpoint resumed from and written (NeRF training).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// The images' directory.
    #[command(flatten)]
    pub out: OutDirArg,
}

/// `nerf targets`.
#[derive(Args, Debug)]
pub struct TargetsArgs {
    /// The training config (e.g. train_box) and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// `nerf eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// The config and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Which split to score.
    #[arg(long, value_enum, default_value = "test")]
    pub split: SplitArg,
    /// The checkpoint scored.
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// The dataset.
    #[command(flatten)]
    pub data: DataDirArg,
    /// Write each predicted view as <frame>.png into this directory.
    #[arg(long)]
    pub save_images: Option<PathBuf>,
    /// Score only the first N views.
    #[arg(long, value_parser = at_least_one)]
    pub limit: Option<usize>,
    /// Print JSON instead of a summary.
    #[arg(long)]
    pub json: bool,
    /// Composite ground truth and prediction on white (the NeRF papers' protocol) instead of
    /// black (the homework's); the same as `renderer.white_background=True`.
    #[arg(long)]
    pub white: bool,
}

/// `nerf process`.
#[derive(Args, Debug)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["images", "video"])))]
pub struct ProcessArgs {
    /// The folder of photos (PNG and JPEG, subfolders included, sorted by path).
    #[arg(long)]
    pub images: Option<PathBuf>,
    /// A video (anything ffmpeg reads): frames spread over the clip, the sharpest of each
    /// stretch, are written to OUT/images and matched sequentially. Needs ffmpeg (on PATH,
    /// or NERF_FFMPEG).
    #[arg(long)]
    pub video: Option<PathBuf>,
    /// Frames kept from --video (3 to 2000; default 100).
    #[arg(long, value_parser = frame_count, conflicts_with = "images")]
    pub frames: Option<usize>,
    /// The capture folder to write: images/, colmap/ (the database, the sparse models and
    /// each stage's log) and transforms.json. It must not hold an earlier run's outputs.
    #[arg(long)]
    pub out: PathBuf,
    /// Which COLMAP: pycolmap (COLMAP 4 through the Python wheel: `pip install pycolmap`),
    /// colmap (the program: `colmap` on PATH or NERF_COLMAP), or auto (pycolmap when Python
    /// imports it and NERF_COLMAP is not set, else the program).
    #[arg(long, value_enum, default_value = "auto")]
    pub sfm: SfmArg,
    /// How COLMAP pairs images: exhaustive (every pair), sequential (neighbours in name
    /// order, and with pycolmap retrieval pairs that close loops), retrieval (each image with
    /// its most similar ones; pycolmap only), or auto (with pycolmap: exhaustive up to 50
    /// images, else sequential for a video or photos numbered in order, else retrieval; with
    /// the program: sequential for --video, for photos exhaustive up to 100 images).
    #[arg(long, value_enum, default_value = "auto")]
    pub matcher: MatcherArg,
    /// A COLMAP vocabulary tree file for the COLMAP program (e.g.
    /// vocab_tree_flickr100K_words32K.bin from COLMAP 3.8's site): its sequential matching then
    /// also looks for loop closures. With pycolmap it is not used: retrieval pairs close loops.
    #[arg(long)]
    pub vocab_tree: Option<PathBuf>,
    /// Most SIFT features kept per photo: matching time grows with its square (100 to 65536).
    #[arg(long, default_value_t = crate::process::DEFAULT_MAX_FEATURES, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=65536))]
    pub max_features: usize,
    /// Photos whose longer side is larger than this many pixels are downscaled for feature
    /// extraction (100 to 16384; default 1600 with pycolmap, 3200 with the program).
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=16384))]
    pub max_image_size: Option<usize>,
    /// Runs of COLMAP's mapper, each with its own random seed: the run the others agree with
    /// best is kept, and images the others place elsewhere are left out (1 to 10; default 1
    /// with pycolmap, 3 with the program).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10))]
    pub mapper_runs: Option<u64>,
    /// After mapping, observations further than this many pixels from their point's
    /// projection are dropped and the cameras adjusted again (the mapper itself keeps
    /// COLMAP's 4 px; raise this for blurred or rolling-shutter photos).
    #[arg(long, default_value_t = 1.5, value_parser = positive_pixels)]
    pub max_reprojection_error: f64,
    /// Then train `nerf_scene` on the capture for this many minutes (the checkpoint:
    /// OUT/model.safetensors), as `nerf train --config nerf_scene --data-dir OUT --minutes M`.
    #[arg(long, value_parser = positive_minutes)]
    pub train_minutes: Option<f64>,
    /// Then serve the trained model in the browser viewer (`nerf view`), on --port.
    #[arg(long, requires = "train_minutes")]
    pub view: bool,
    /// The viewer's port with --view (0 picks a free one).
    #[arg(long, default_value_t = 7007, requires = "view")]
    pub port: u16,
}

/// A number of video frames from 3 to 2000.
fn frame_count(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(v) if (3..=2000).contains(&v) => Ok(v),
        _ => Err(format!("{text:?} is not a number of frames from 3 to 2000")),
    }
}

/// A finite number of pixels above 0.
fn positive_pixels(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{text:?} is not a positive number of pixels")),
    }
}

/// `--matcher`.
#[allow(missing_docs)] // each value is what the option's help says
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum MatcherArg {
    Auto,
    Exhaustive,
    Sequential,
    Retrieval,
}

/// `--sfm`.
#[allow(missing_docs)] // each value is what the option's help says
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum SfmArg {
    Auto,
    Pycolmap,
    Colmap,
}

impl From<SfmArg> for crate::process::colmap_run::SfmChoice {
    fn from(m: SfmArg) -> Self {
        match m {
            SfmArg::Auto => Self::Auto,
            SfmArg::Pycolmap => Self::Pycolmap,
            SfmArg::Colmap => Self::Program,
        }
    }
}

impl From<MatcherArg> for crate::process::Matcher {
    fn from(m: MatcherArg) -> Self {
        match m {
            MatcherArg::Auto => Self::Auto,
            MatcherArg::Exhaustive => Self::Exhaustive,
            MatcherArg::Sequential => Self::Sequential,
            MatcherArg::Retrieval => Self::Retrieval,
        }
    }
}

/// `nerf import-torch`.
#[derive(Args, Debug)]
pub struct ImportTorchArgs {
    /// The .pth file (`torch.save(model.state_dict())`, or a dict holding it under
    /// model / model_state_dict / state_dict).
    pub pth: PathBuf,
    /// The config whose implicit_function gives the model's sizes (e.g. nerf_lego).
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Where to write the safetensors checkpoint.
    #[arg(long, default_value = "checkpoints/imported.safetensors")]
    pub out: PathBuf,
}

/// `nerf bench`.
#[derive(Args, Debug)]
#[command(
    after_help = "--config is the SDF scene to time (e.g. box); the NeRF rows use the \
                  built-in nerf_lego and lego configs, at the work of the PyTorch figures. The trained-NeRF rows render \
                  --checkpoint and are skipped when it is missing. The hash-grid rows train \
                  nerf_lego_ngp (from the shipped checkpoints/ngp_lego.safetensors when present) \
                  on the --data-dir lego, render lego_ngp_400 at 400x400, and give their \
                  GFLOP/s as a fraction of the f32 matmul rate measured in the same run."
)]
pub struct BenchArgs {
    /// The SDF scene's config and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Repeats of the box render and the training step (the best is reported; the first
    /// training step is a cold one, so use at least 2); the untrained frame is rendered
    /// min(repeats, 2) times; the trained-NeRF rows render each view once and report the
    /// mean.
    #[arg(long, default_value_t = 3, value_parser = at_least_one)]
    pub repeats: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// The trained-NeRF rows' checkpoint.
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// The trained-NeRF rows' dataset.
    #[command(flatten)]
    pub data: DataDirArg,
    /// Test views rendered for the trained-NeRF benchmark.
    #[arg(long, default_value_t = 5, value_parser = at_least_one)]
    pub views: usize,
    /// CI-sized run: one repeat and one view (in place of --repeats and --views), no
    /// whole-command rows, a few hash-grid training steps and a smaller square matmul.
    #[arg(long)]
    pub quick: bool,
    /// Timed steps of each hash-grid training row (default: 24 at the shipped samples per
    /// step, 8 at 2^18; 2 with --quick).
    #[arg(long, value_parser = at_least_one)]
    pub train_steps: Option<usize>,
    /// Only these groups of rows (repeat or separate with commas; all when not given).
    /// Without matmul, the NeRF and hash-grid rows give no fraction of the matmul rate; without
    /// memory, the hash-grid rows give no fraction of the random-read rate.
    #[arg(long, value_enum, value_delimiter = ',')]
    pub only: Vec<crate::bench::RowGroup>,
}

/// `nerf report`.
#[derive(Args, Debug)]
#[command(after_help = "The lego section renders --checkpoint with the \
                  built-in lego config; a missing checkpoint or dataset is an error unless \
                  --no-lego is given.")]
pub struct ReportArgs {
    /// Output directory (report.md, report.json, plots).
    #[arg(long, default_value = "reports")]
    pub out_dir: PathBuf,
    /// CI-sized run: small images, fewer sample counts and views, one repeat.
    #[arg(long)]
    pub quick: bool,
    /// The lego section's checkpoint.
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// Leave out the lego section (no checkpoint or dataset needed).
    #[arg(long, conflicts_with_all = ["checkpoint", "data_dir", "views"])]
    pub no_lego: bool,
    /// The lego section's dataset.
    #[command(flatten)]
    pub data: DataDirArg,
    /// Test views for the lego section (default 5; 2 with --quick).
    #[arg(long, value_parser = at_least_one)]
    pub views: Option<usize>,
    /// Training logs to plot (default: the checkpoint's .log.jsonl and
    /// checkpoints/homework/nerf_lego.log.jsonl).
    #[arg(long = "log")]
    pub logs: Vec<PathBuf>,
}

/// `nerf view`.
#[derive(Args, Debug)]
#[command(
    after_help = "The overrides' sampler, renderer, cameras and data.image_size set the \
                  defaults of /render.png."
)]
pub struct ViewArgs {
    /// The config (e.g. lego, box) and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The checkpoint shown (NeRF configs).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// Port to listen on (0 picks a free one; the address is printed).
    #[arg(long, default_value_t = 7007)]
    pub port: u16,
    /// Address to bind; the default serves this machine only. Requests are answered only when
    /// their Host header names the viewer: loopback names when bound to loopback, else the
    /// bound address and this value.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    /// Milliseconds a connection may take to send a request head, from its opening or its
    /// previous response (so also the idle keep-alive time); tests shorten it.
    #[arg(long, hide = true, default_value_t = 10_000,
          value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    pub header_timeout_ms: u64,
}

/// `nerf export …`.
#[derive(Subcommand, Debug)]
pub enum ExportCommand {
    /// Marching cubes on the density, vertex colours from the field: a binary PLY mesh.
    Mesh(ExportMeshArgs),
    /// The expected-depth points of the dataset's views (opacity above 0.5) with their
    /// colours: a binary PLY point cloud (data.image_size sets the rendering size).
    Points(ExportPointsArgs),
    /// The model of a training checkpoint without the optimiser's state (an NGP's hash table
    /// as f16): what rendering and evaluation need, a fraction of the size.
    Model(ExportModelArgs),
    /// A depth .npy (H, W) and a viridis PNG for each view of a split.
    Depth(ExportDepthArgs),
}

/// `nerf export mesh`.
#[derive(Args, Debug)]
pub struct ExportMeshArgs {
    /// The config (e.g. lego, box) and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The checkpoint meshed (NeRF configs).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// Marching-cubes cells per side of the box (the NeRF's occupancy-grid box, or a box
    /// around the SDF's shape), 1 to 512.
    #[arg(long, default_value_t = 256)]
    pub resolution: usize,
    /// Density at the surface: NeRF sigma (default 10), or the homework's SDF density
    /// between 0 and alpha (default alpha/2, the SDF's zero level).
    #[arg(long)]
    pub threshold: Option<f64>,
    /// The PLY file to write.
    #[arg(long)]
    pub out: PathBuf,
}

/// `nerf export model`.
#[derive(Args, Debug)]
pub struct ExportModelArgs {
    /// The config (e.g. nerf_lego_ngp) and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The training checkpoint read.
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// The safetensors file to write.
    #[arg(long)]
    pub out: PathBuf,
}

/// The views an export renders, past their split: `--data-dir` and `--limit`.
#[derive(Args, Debug)]
pub struct ExportViewsArgs {
    /// The dataset (NeRF configs).
    #[command(flatten)]
    pub data: DataDirArg,
    /// Only the first N views.
    #[arg(long, value_parser = at_least_one)]
    pub limit: Option<usize>,
}

/// `nerf export points`.
#[derive(Args, Debug)]
pub struct ExportPointsArgs {
    /// The config (e.g. lego) and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The checkpoint rendered (NeRF configs).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// Dataset split whose views are rendered (NeRF; SDF scenes use the surround cameras).
    #[arg(long, value_enum, default_value = "train")]
    pub split: SplitArg,
    /// The views' dataset and count.
    #[command(flatten)]
    pub views: ExportViewsArgs,
    /// The PLY file to write.
    #[arg(long)]
    pub out: PathBuf,
}

/// `nerf export depth`.
#[derive(Args, Debug)]
pub struct ExportDepthArgs {
    /// The config (e.g. lego) and its overrides.
    #[command(flatten)]
    pub config: ConfigArgs,
    /// The checkpoint rendered (NeRF configs).
    #[command(flatten)]
    pub checkpoint: CheckpointArg,
    /// Dataset split (NeRF; SDF scenes use the surround cameras).
    #[arg(long, value_enum, default_value = "test")]
    pub split: SplitArg,
    /// The views' dataset and count.
    #[command(flatten)]
    pub views: ExportViewsArgs,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
}

/// `--split`: a dataset split.
#[allow(missing_docs)] // each value is what the option's help says
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum SplitArg {
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

/// A positive, finite number of minutes, for clap.
fn positive_minutes(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(m) if m.is_finite() && m > 0.0 => Ok(m),
        Ok(_) => Err("must be a positive number of minutes".into()),
        Err(e) => Err(e.to_string()),
    }
}

/// A count of at least 1, for clap.
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn config_name_means_config() {
        let parsed = Cli::try_parse_from(["nerf", "render", "--config-name", "box"]);
        match parsed.map(|c| c.command) {
            Ok(Command::Render(args)) => assert_eq!(args.config.config, "box"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn run_takes_the_training_options() {
        let parsed = Cli::try_parse_from(["nerf", "run", "--config", "nerf_lego", "--epochs", "1"]);
        assert!(parsed.is_ok(), "{:?}", parsed.err());
    }

    /// Every option that several subcommands take (`--config`, `--checkpoint`, `--data-dir`,
    /// `--out-dir`, `--epochs`, …) has one help text wherever it appears.
    #[test]
    fn shared_options_read_the_same_in_every_subcommand() {
        fn collect(
            cmd: &clap::Command,
            path: &str,
            seen: &mut std::collections::BTreeMap<String, Vec<(String, String)>>,
        ) {
            for arg in cmd.get_arguments() {
                let id = arg.get_id().to_string();
                let help = arg
                    .get_long_help()
                    .or(arg.get_help())
                    .map(|h| h.to_string());
                seen.entry(id)
                    .or_default()
                    .push((path.to_string(), help.unwrap_or_default()));
            }
            for sub in cmd.get_subcommands() {
                collect(sub, &format!("{path} {}", sub.get_name()), seen);
            }
        }
        let mut seen = Default::default();
        collect(&Cli::command(), "nerf", &mut seen);
        for id in [
            "config",
            "overrides",
            "checkpoint",
            "data_dir",
            "epochs",
            "minutes",
            "overwrite",
        ] {
            let uses = &seen[id];
            assert!(uses.len() >= 2, "{id}: {uses:?}");
            assert!(
                uses.iter().all(|(_, help)| help == &uses[0].1),
                "{id} reads differently: {uses:#?}"
            );
        }
        // Every subcommand that reads a config or a checkpoint takes the shared option.
        let subcommands = |id: &str| seen[id].iter().map(|(p, _)| p.clone()).collect::<Vec<_>>();
        assert_eq!(
            subcommands("config"),
            [
                "nerf run",
                "nerf render",
                "nerf train",
                "nerf targets",
                "nerf eval",
                "nerf import-torch",
                "nerf bench",
                "nerf view",
                "nerf export mesh",
                "nerf export points",
                "nerf export model",
                "nerf export depth"
            ]
        );
        let checkpoint = subcommands("checkpoint");
        for cmd in [
            "nerf run",
            "nerf render",
            "nerf train",
            "nerf eval",
            "nerf bench",
        ] {
            assert!(checkpoint.iter().any(|c| c == cmd), "{cmd}: {checkpoint:?}");
        }
        for cmd in ["nerf run", "nerf train"] {
            assert!(subcommands("epochs").iter().any(|c| c == cmd), "{cmd}");
        }
    }
}
