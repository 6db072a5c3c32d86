//! What each `nerf` subcommand does with its parsed arguments ([`crate::cli`]): turns
//! them into the library's parameters, runs the job, and prints what it wrote. Every line
//! printed goes through [`say`], so a closed stdout is an error ([`StdoutError`]) rather than
//! a panic; a training run stopped by a signal ends in [`Stopped`].

use std::path::Path;

use crate::render::scene_frame::adopt_stored_settings;
use anyhow::Result;
use candle_core::Device;

use crate::cli::{
    BenchArgs, CheckpointArg, ConfigArgs, EvalArgs, ExportCommand, ExportViewsArgs,
    ImportTorchArgs, ProcessArgs, RenderArgs, ReportArgs, RunArgs, SplitArg, TargetsArgs,
    TrainArgs, TrainingArgs, ViewArgs,
};
use crate::export::ViewSelection;
use crate::train::jobs::{self, NerfTrainOptions, RunJob, TrainJob, TrainOutcome};
use nerf::config::Config;

/// Writing to stdout failed (a closed pipe, a full disk).
#[derive(Debug)]
pub struct StdoutError(pub std::io::Error);

impl std::fmt::Display for StdoutError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "cannot write to stdout: {}", self.0)
    }
}

impl std::error::Error for StdoutError {}

/// Training was stopped by a signal; the message says where and how to resume.
#[derive(Debug)]
pub struct Stopped(pub String);

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Stopped {}

/// Writes `line` and a newline to stdout; `println!` would panic when that fails.
pub fn say(line: &str) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")
        .and_then(|()| out.flush())
        .map_err(|e| anyhow::Error::new(StdoutError(e)))
}

/// Prints `wrote PATH` for each path.
fn say_written(paths: &[std::path::PathBuf]) -> Result<()> {
    paths
        .iter()
        .try_for_each(|p| say(&format!("wrote {}", p.display())))
}

/// The NeRF training options of `--data-dir` and the training flags.
fn train_options(data_dir: Option<std::path::PathBuf>, t: TrainingArgs) -> NerfTrainOptions {
    NerfTrainOptions {
        data_dir,
        epochs: t.epochs,
        minutes: t.minutes,
        overwrite: t.overwrite,
    }
}

/// `nerf run`: the job of the config's `type`; a render config given a training flag is an
/// error naming it.
pub fn run(args: RunArgs, device: &Device) -> Result<()> {
    let RunArgs {
        config: c,
        out,
        checkpoint,
        data,
        training,
    } = args;
    let options = train_options(data.data_dir, training);
    let loaded = c.load()?;
    match jobs::run_job(&loaded, &c.config)? {
        RunJob::Render => {
            let kind = loaded.kind.map_or("", |k| k.name());
            let does = format!("has `type: {kind}`, which renders");
            jobs::refuse_nerf_training_flags(&options.flags_given(), &c.config, &does)?;
            let written = crate::render::scene::render_scene(
                &loaded,
                checkpoint.checkpoint.as_deref(),
                &out.out_dir,
                false,
                device,
            )?;
            say_written(&written)
        }
        RunJob::Train(job) => {
            let (config, job) = jobs::prepare_training(
                loaded,
                &c.config,
                &c.overrides,
                job,
                checkpoint.checkpoint.as_deref(),
                &options,
            )?;
            train_and_say(&config, job, &options, &out.out_dir, device)
        }
    }
}

/// `nerf render`: the surround views (or a camera path) into the output directory.
pub fn render(args: RenderArgs, device: &Device) -> Result<()> {
    let mut config = args.config.load()?;
    let checkpoint = args.checkpoint.checkpoint.as_deref();
    let path = config.checkpoint(checkpoint);
    adopt_stored_settings(&mut config, &path, true)?;
    let out_dir = &args.out.out_dir;
    let written = match &args.camera_path {
        Some(path) => crate::render::path_frames::render_camera_path(
            &config, checkpoint, path, out_dir, device,
        )?,
        None => crate::render::scene::render_scene(&config, checkpoint, out_dir, args.raw, device)?,
    };
    say_written(&written)
}

/// `nerf train`: the training job of the config, `--checkpoint` as its
/// `training.checkpoint_path`.
pub fn train(args: TrainArgs, device: &Device) -> Result<()> {
    let options = train_options(args.data.data_dir, args.training);
    let (config, job) = jobs::load_training(
        &args.config.config,
        &args.config.overrides,
        args.checkpoint.checkpoint.as_deref(),
        &options,
    )?;
    train_and_say(&config, job, &options, &args.out.out_dir, device)
}

/// Runs a training job, stopping after the current step on SIGINT/SIGTERM, and prints what it
/// did (or, stopped, how to resume).
fn train_and_say(
    config: &Config,
    job: TrainJob,
    options: &NerfTrainOptions,
    out_dir: &Path,
    device: &Device,
) -> Result<()> {
    let stop = match job {
        TrainJob::Nerf => Some(crate::train::nerf_run::stop_on_signal()?),
        TrainJob::Sdf => None,
    };
    match jobs::train(config, job, options, out_dir, stop, device)? {
        TrainOutcome::Done(lines) => lines.iter().try_for_each(|l| say(l)),
        TrainOutcome::Stopped { info, checkpoint } => Err(anyhow::Error::new(Stopped(format!(
            "stopped at epoch {} step {}; checkpoint {}; resume with: {}",
            info.epoch,
            info.adam_step,
            checkpoint.display(),
            resume_command(config.training()?.resume)
        )))),
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

/// `nerf targets`: writes the training config's target images.
pub fn targets(args: TargetsArgs, device: &Device) -> Result<()> {
    let config = args.config.load()?;
    say_written(&crate::train::box_fit::write_targets(&config, device)?)
}

/// `nerf eval`: PSNR and SSIM over a split, as a summary or JSON.
pub fn eval(args: EvalArgs, device: &Device) -> Result<()> {
    let mut config = args.config.load()?;
    let path = config.checkpoint(args.checkpoint.checkpoint.as_deref());
    adopt_stored_settings(&mut config, &path, false)?;
    if args.white {
        config.renderer.white_background = true;
    }
    let data_dir = jobs::data_dir_for(&config, args.data.data_dir);
    let report = crate::eval::eval_nerf(
        &config,
        args.checkpoint.checkpoint.as_deref(),
        &data_dir,
        args.split.into(),
        args.save_images.as_deref(),
        args.limit,
        device,
    )?;
    if args.json {
        say(&serde_json::to_string_pretty(&report)?)
    } else {
        say(&report.summary())
    }
}

/// `nerf import-torch`: converts a PyTorch state dict; the note goes to stderr.
pub fn import_torch(args: ImportTorchArgs) -> Result<()> {
    let config = args.config.load()?;
    let n = nerf::io::torch::import_torch(
        &args.pth,
        &config.field_spec()?.parameter_shapes()?,
        &args.out,
    )?;
    nerf::core::term::note(&format!(
        "wrote {} ({n} parameters from {})",
        args.out.display(),
        args.pth.display()
    ));
    Ok(())
}

/// `nerf bench`: times the jobs and prints a table or JSON.
pub fn bench(args: BenchArgs, device: &Device) -> Result<()> {
    let config = args.config.load()?;
    let lego_config = Config::load("lego", &[])?;
    let lego = crate::bench::LegoBench {
        checkpoint: lego_config.checkpoint(args.checkpoint.checkpoint.as_deref()),
        data_dir: jobs::data_dir_for(&lego_config, args.data.data_dir),
        views: if args.quick { 1 } else { args.views },
        quick: args.quick,
        train_steps: args.train_steps,
    };
    let repeats = if args.quick { 1 } else { args.repeats };
    let report = crate::bench::run_benchmarks(&config, repeats, Some(&lego), &args.only, device)?;
    if args.json {
        say(&serde_json::to_string_pretty(&report)?)
    } else {
        say(crate::bench::format_table(&report).trim_end())
    }
}

/// `nerf report`: measures and writes the report.
pub fn report(args: ReportArgs, device: &Device) -> Result<()> {
    let lego_config = Config::load("lego", &[])?;
    let checkpoint = lego_config.checkpoint(args.checkpoint.checkpoint.as_deref());
    let training_logs = if args.logs.is_empty() {
        crate::report::default_training_logs(&checkpoint)
    } else {
        args.logs
    };
    let options = crate::report::ReportOptions {
        out_dir: args.out_dir,
        quick: args.quick,
        checkpoint,
        data_dir: jobs::data_dir_for(&lego_config, args.data.data_dir),
        views: args.views,
        training_logs,
        ngp_checkpoint: Some(nerf::config::SHIPPED_NGP_CHECKPOINT.into()),
        lego: !args.no_lego,
    };
    say_written(&crate::report::write_report(&options, device)?)
}

/// `nerf view`: serves until killed.
pub fn view(args: ViewArgs, device: &Device) -> Result<()> {
    let mut config = args.config.load()?;
    let checkpoint = args.checkpoint.checkpoint.as_deref();
    let path = config.checkpoint(checkpoint);
    adopt_stored_settings(&mut config, &path, true)?;
    let scene = crate::render::scene::load_scene_field(&config, checkpoint, device)?;
    let views = match scene {
        crate::render::scene::SceneField::Nerf(_) => {
            crate::render::scene_frame::render_cameras(&config, &config.checkpoint(checkpoint))?
        }
        crate::render::scene::SceneField::Sdf { .. } => {
            crate::render::scene_frame::DefaultViews::surround(&config)
        }
    };
    let options = crate::view::ViewOptions {
        host: args.host,
        port: args.port,
        header_timeout: std::time::Duration::from_millis(args.header_timeout_ms),
    };
    crate::view::serve(
        &config,
        &args.config.config,
        scene,
        &views,
        &options,
        device,
    )
}

/// The config as `checkpoint` was trained ([`as_trained`]), and the views an export renders:
/// `split` of the dataset that `--data-dir` (or the config as given) names, the first
/// `--limit` of them.
fn export_views(
    config: &ConfigArgs,
    split: SplitArg,
    views: ExportViewsArgs,
    checkpoint: Option<&std::path::Path>,
) -> Result<(Config, ViewSelection)> {
    let config = config.load()?;
    let selection = ViewSelection {
        split: split.into(),
        data_dir: jobs::data_dir_for(&config, views.data.data_dir),
        limit: views.limit,
    };
    Ok((as_trained(config, checkpoint)?, selection))
}

/// `config` read as the model in `checkpoint` (or the config's) was trained
/// ([`adopt_stored_settings`]: its background, depths and object box).
fn as_trained(mut config: Config, checkpoint: Option<&std::path::Path>) -> Result<Config> {
    let path = config.checkpoint(checkpoint);
    adopt_stored_settings(&mut config, &path, false)?;
    Ok(config)
}

/// `nerf export …`: runs the export and says what it wrote.
pub fn export(what: ExportCommand, device: &Device) -> Result<()> {
    use crate::export::{export_depth, export_mesh, export_points, MeshOptions};
    match what {
        ExportCommand::Mesh(a) => {
            let config = as_trained(a.config.load()?, a.checkpoint.checkpoint.as_deref())?;
            let options = MeshOptions {
                resolution: a.resolution,
                threshold: a.threshold,
                out: a.out,
            };
            let m = export_mesh(
                &config,
                a.checkpoint.checkpoint.as_deref(),
                &options,
                device,
            )?;
            say(&format!(
                "wrote {} ({} vertices, {} triangles, threshold {}, {:.1} s)",
                options.out.display(),
                m.vertices,
                m.faces,
                m.threshold,
                m.seconds
            ))
        }
        ExportCommand::Points(a) => {
            let checkpoint = a.checkpoint.checkpoint.as_deref();
            let (config, views) = export_views(&a.config, a.split, a.views, checkpoint)?;
            let n = export_points(&config, checkpoint, &views, &a.out, device)?;
            say(&format!("wrote {} ({n} points)", a.out.display()))
        }
        ExportCommand::Model(a) => {
            let checkpoint = a.checkpoint.checkpoint.as_deref();
            let config = as_trained(a.config.load()?, checkpoint)?;
            let e = crate::export::model_file::export_model(&config, checkpoint, &a.out, device)?;
            say(&format!(
                "wrote {} ({} tensors, {:.1} MB; largest f16 rounding of the table {:.1e})",
                a.out.display(),
                e.tensors,
                e.bytes as f64 / 1e6,
                e.table_rounding
            ))
        }
        ExportCommand::Depth(a) => {
            let checkpoint = a.checkpoint.checkpoint.as_deref();
            let (config, views) = export_views(&a.config, a.split, a.views, checkpoint)?;
            let written = export_depth(&config, checkpoint, &views, &a.out, device)?;
            say(&format!(
                "wrote {} files into {}",
                written.len(),
                a.out.display()
            ))
        }
    }
}

/// `nerf process`: photos to a capture through COLMAP ([`crate::process::process`]);
/// prints what it wrote, how many images registered and the command that trains on it; with
/// `--train-minutes` trains `nerf_scene` on it, and with `--view` serves the model, saying each
/// stage's time and the whole.
pub fn process(args: ProcessArgs, device: &Device) -> Result<()> {
    let start = std::time::Instant::now();
    let (train_minutes, view, port) = (args.train_minutes, args.view, args.port);
    let out = args.out.clone();
    process_capture(args)?;
    let Some(minutes) = train_minutes else {
        return Ok(());
    };
    let sfm_seconds = start.elapsed().as_secs_f64();
    let checkpoint = CheckpointArg {
        checkpoint: Some(out.join(CAPTURE_MODEL)),
    };
    let config = |overrides: Vec<String>| ConfigArgs {
        config: "nerf_scene".into(),
        overrides,
    };
    train(
        TrainArgs {
            config: config(Vec::new()),
            data: crate::cli::DataDirArg {
                data_dir: Some(out.clone()),
            },
            training: crate::cli::TrainingArgs {
                minutes: Some(minutes),
                ..Default::default()
            },
            checkpoint: checkpoint.clone(),
            out: crate::cli::OutDirArg {
                out_dir: out.join("previews"),
            },
        },
        device,
    )?;
    let total = start.elapsed().as_secs_f64();
    say(&format!(
        "photos to model in {:.1} min: structure from motion {:.1} min, training {:.1} min",
        total / 60.0,
        sfm_seconds / 60.0,
        (total - sfm_seconds) / 60.0
    ))?;
    if !view {
        return say(&format!(
            "view it: nerf view --config nerf_scene --checkpoint {}",
            out.join(CAPTURE_MODEL).display()
        ));
    }
    crate::commands::view(
        ViewArgs {
            config: config(Vec::new()),
            checkpoint,
            port,
            host: "127.0.0.1".into(),
            header_timeout_ms: 10_000,
        },
        device,
    )
}

/// The checkpoint `nerf process --train-minutes` writes in its `--out` folder.
pub const CAPTURE_MODEL: &str = "model.safetensors";

/// [`process`] without the training and viewing.
fn process_capture(args: ProcessArgs) -> Result<()> {
    use crate::process::Source;
    let source = match (args.images, args.video) {
        (Some(images), _) => Source::Images(images),
        (None, Some(file)) => Source::Video {
            file,
            frames: args
                .frames
                .unwrap_or(crate::process::video_frames::DEFAULT_FRAMES),
        },
        (None, None) => anyhow::bail!("nerf process needs --images DIR or --video FILE"),
    };
    let options = crate::process::ProcessOptions {
        source,
        out: args.out,
        matcher: args.matcher.into(),
        vocab_tree: args.vocab_tree,
        features: crate::process::FeatureOptions {
            max_features: args.max_features,
            max_image_size: args.max_image_size,
        },
        mapping: crate::process::mapper::MappingOptions {
            runs: args.mapper_runs,
            max_reprojection_error: args.max_reprojection_error,
        },
        sfm: args.sfm.into(),
    };
    let summary = crate::process::process(&options)?;
    let times: Vec<String> = summary
        .stages
        .iter()
        .map(|s| format!("{} {:.1} s", s.stage, s.seconds))
        .collect();
    let left_out = match summary.left_out.len() {
        0 => String::new(),
        k => format!(
            ", {k} of them left out: the mapper runs placed them apart ({})",
            summary
                .left_out
                .iter()
                .map(|(name, _)| name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    say(&format!(
        "wrote {} ({} of {} images registered{left_out}; COLMAP: {}, {} mapper runs)",
        summary.transforms.display(),
        summary.registered,
        summary.images,
        times.join(", "),
        summary.mapper_runs.len()
    ))?;
    let white = summary
        .white_border
        .filter(|&f| f >= nerf::io::dataset::backdrop::WHITE_FRACTION);
    match white {
        Some(fraction) => say(&format!(
            "the photos' borders are plain white ({:.0}% of border pixels), which nerf_scene \
             detects and renders on: nerf train --config nerf_scene --data-dir {}",
            100.0 * fraction,
            options.out.display()
        )),
        None => say(&format!(
            "train on it: nerf train --config nerf_scene --data-dir {}",
            options.out.display()
        )),
    }
}
