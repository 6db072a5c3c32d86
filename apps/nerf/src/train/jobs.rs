//! The jobs of the `nerf` command, chosen as the homework's `main.py` chooses them: by the
//! config's top-level `type` (`nerf run`), or by the subcommand (`nerf render`, `nerf train`),
//! which checks that the config suits it.
//!
//! * `render` and `render_nerf` configs render (`nerf render`): an SDF scene's outputs, or a
//!   NeRF's surround GIF from its checkpoint.
//! * `train` configs fit an SDF volume to images ([`crate::train::box_fit`]); `train_nerf`
//!   configs train a NeRF ([`crate::train::nerf_run`]). `nerf render` of a training config renders
//!   its initial volume or its training checkpoint; `nerf train` of a render config is an
//!   error that names the command to use.
//! * A config without `type` (an extension) is trained by its field: an SDF volume is fitted,
//!   a NeRF trained.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use anyhow::{bail, Result};
use candle_core::Device;

use crate::train::box_fit::train_sdf;
use nerf::config::{Config, JobKind};
use nerf::train::fit::FitOutcome;

/// What `nerf train` (or `nerf run` of a training config) does with a config.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrainJob {
    /// Fit an SDF volume's `opt: True` parameters to images (`type: train`).
    Sdf,
    /// Train a NeRF on a dataset (`type: train_nerf`).
    Nerf,
}

/// The training job for `config` (named `name` in messages); an error for a render config
/// (naming `nerf render`) or a `type` its field cannot do.
pub fn train_job(config: &Config, name: &str) -> Result<TrainJob> {
    let nerf = !config.implicit_function.is_sdf_volume();
    match config.kind {
        Some(kind) if kind.renders() => bail!(
            "config {name} has `type: {}`: it renders, it does not train; run `nerf render --config {name}` (or `nerf run --config {name}`){}",
            kind.name(),
            if nerf {
                "; to train this scene: `nerf train --config nerf_lego_fast` (or nerf_lego, nerf_lego_ngp)"
            } else {
                ""
            }
        ),
        Some(JobKind::Train) if nerf => bail!(
            "config {name} has `type: train`, which fits an SDF volume, but its implicit_function is a nerf (use `type: train_nerf`)"
        ),
        Some(JobKind::TrainNerf) if !nerf => bail!(
            "config {name} has `type: train_nerf`, but its implicit_function is an sdf_volume (use `type: train` to fit it)"
        ),
        _ if nerf => Ok(TrainJob::Nerf),
        _ => Ok(TrainJob::Sdf),
    }
}

/// What `nerf run` does: the job of the config's `type`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunJob {
    /// `render` / `render_nerf`.
    Render,
    /// `train` / `train_nerf`.
    Train(TrainJob),
}

/// The job `nerf run` runs for `config`; an error when it has no `type`.
pub fn run_job(config: &Config, name: &str) -> Result<RunJob> {
    match config.kind {
        None => bail!(
            "config {name} has no `type` (render, render_nerf, train or train_nerf); use `nerf render` or `nerf train`"
        ),
        Some(kind) if kind.renders() => Ok(RunJob::Render),
        Some(_) => Ok(RunJob::Train(train_job(config, name)?)),
    }
}

/// Options of the NeRF training job.
#[derive(Debug, Clone, Default)]
pub struct NerfTrainOptions {
    /// Dataset directory (`--data-dir`; default `data.data_dir`, else
    /// `../shared/data/<dataset_name>`).
    pub data_dir: Option<PathBuf>,
    /// Stop after this many epochs in this run.
    pub epochs: Option<usize>,
    /// Stop after this many minutes of training in this run.
    pub minutes: Option<f64>,
    /// With `training.resume: False`, replace an existing checkpoint and its log.
    pub overwrite: bool,
}

impl NerfTrainOptions {
    /// The command-line flags these options were given by (`--data-dir`, `--epochs`,
    /// `--minutes`, `--overwrite`), for an error where they mean nothing.
    pub fn flags_given(&self) -> Vec<&'static str> {
        [
            (self.data_dir.is_some(), "--data-dir"),
            (self.epochs.is_some(), "--epochs"),
            (self.minutes.is_some(), "--minutes"),
            (self.overwrite, "--overwrite"),
        ]
        .into_iter()
        .filter_map(|(given, flag)| given.then_some(flag))
        .collect()
    }
}

/// An error naming `flags` when there are any: they are for NeRF training, and config `name`
/// `does` something else (e.g. "has `type: render`, which renders").
pub fn refuse_nerf_training_flags(flags: &[&str], name: &str, does: &str) -> Result<()> {
    if flags.is_empty() {
        return Ok(());
    }
    bail!(
        "{} {} for NeRF training, and config {name} {does}",
        flags.join(", "),
        if flags.len() == 1 { "is" } else { "are" }
    )
}

/// The override that sets `training.checkpoint_path` to `path` (what `--checkpoint` means to
/// a training run), its value quoted so that YAML reads it as the string it is.
pub fn checkpoint_path_override(path: &Path) -> Result<String> {
    let text = path
        .to_str()
        .ok_or_else(|| anyhow::anyhow!("--checkpoint {}: not UTF-8", path.display()))?;
    Ok(format!(
        "training.checkpoint_path={}",
        serde_json::to_string(text)?
    ))
}

/// A training run's config and job: config `name` loaded with `overrides`, checked by
/// [`train_job`], with `checkpoint` (`--checkpoint`) applied as the override
/// `training.checkpoint_path=PATH` after the others. An SDF fit given `checkpoint` or any of
/// `options` (all NeRF training's) is an error naming them.
pub fn load_training(
    name: &str,
    overrides: &[String],
    checkpoint: Option<&Path>,
    options: &NerfTrainOptions,
) -> Result<(Config, TrainJob)> {
    let config = Config::load(name, overrides)?;
    let job = train_job(&config, name)?;
    prepare_training(config, name, overrides, job, checkpoint, options)
}

/// [`load_training`] for a config already loaded from `name` with `overrides` whose job is
/// `job`.
pub fn prepare_training(
    config: Config,
    name: &str,
    overrides: &[String],
    job: TrainJob,
    checkpoint: Option<&Path>,
    options: &NerfTrainOptions,
) -> Result<(Config, TrainJob)> {
    match (job, checkpoint) {
        (TrainJob::Sdf, _) => {
            let mut flags = options.flags_given();
            if checkpoint.is_some() {
                flags.insert(0, "--checkpoint");
            }
            refuse_nerf_training_flags(
                &flags,
                name,
                "fits an SDF volume (its length is training.num_epochs)",
            )?;
            Ok((config, job))
        }
        (TrainJob::Nerf, None) => Ok((config, job)),
        (TrainJob::Nerf, Some(path)) => {
            let mut with_checkpoint = overrides.to_vec();
            with_checkpoint.push(checkpoint_path_override(path)?);
            Ok((Config::load(name, &with_checkpoint)?, job))
        }
    }
}

/// How a training job ended.
#[derive(Debug, Clone)]
pub enum TrainOutcome {
    /// It ran to its end; the lines to print.
    Done(Vec<String>),
    /// A signal stopped NeRF training after a step; the checkpoint holds it.
    Stopped {
        /// Progress at the stop (boxed: it is much larger than the other variant).
        info: Box<nerf::io::checkpoint::CheckpointInfo>,
        /// The checkpoint written.
        checkpoint: PathBuf,
    },
}

/// The dataset directory: `given`, else `data.data_dir`, else the default for the dataset
/// name (lego when unnamed).
pub fn data_dir_for(config: &Config, given: Option<PathBuf>) -> PathBuf {
    given
        .or_else(|| config.data.data_dir.clone())
        .unwrap_or_else(|| {
            nerf::io::dataset::default_data_dir(
                config.data.dataset_name.as_deref().unwrap_or("lego"),
            )
        })
}

/// Runs the training job `job` of `config`, writing images into `out_dir`; `stop` ends NeRF
/// training after the current step. Done carries the lines to print (the homework's `Box
/// center` and `Box side lengths` for a box fit).
pub fn train(
    config: &Config,
    job: TrainJob,
    nerf: &NerfTrainOptions,
    out_dir: &Path,
    stop: Option<&AtomicBool>,
    device: &Device,
) -> Result<TrainOutcome> {
    match job {
        TrainJob::Sdf => {
            let o = train_sdf(config, out_dir, device)?;
            let mut lines = fit_summary(&o.fitted);
            lines.push(format!(
                "{} steps in {:.1} s, final loss {:.3e}",
                o.report.steps, o.report.seconds, o.report.final_loss
            ));
            lines.extend(o.written.iter().map(|p| format!("wrote {}", p.display())));
            Ok(TrainOutcome::Done(lines))
        }
        TrainJob::Nerf => {
            let data_dir = data_dir_for(config, nerf.data_dir.clone());
            let paths = config.train_paths(out_dir)?;
            crate::train::nerf_run::check_fresh_start(config, &paths, nerf.overwrite)?;
            let outcome = crate::train::nerf_run::train_nerf(
                config,
                &data_dir,
                &paths,
                nerf::train::fit::RunLimits {
                    epochs: nerf.epochs,
                    seconds: nerf.minutes.map(|m| m * 60.0),
                },
                stop,
                device,
            )?;
            Ok(match outcome {
                FitOutcome::Finished(info) => TrainOutcome::Done(vec![format!(
                    "trained to epoch {}{} ({} Adam steps, {:.1} min); checkpoint {}",
                    info.epoch,
                    match info.step_in_epoch {
                        0 => String::new(),
                        s => format!(" step {s}"),
                    },
                    info.adam_step,
                    info.wall_seconds / 60.0,
                    paths.checkpoint.display()
                )]),
                FitOutcome::Stopped(info) => TrainOutcome::Stopped {
                    info: Box::new(info),
                    checkpoint: paths.checkpoint,
                },
            })
        }
    }
}

/// The homework's printout of the fitted shape: `Box center: (x, y, z)` and `Box side
/// lengths: (x, y, z)` (a sphere: `Sphere center` and `Sphere radius`).
pub fn fit_summary(v: &nerf::core::sdf::SdfVolume) -> Vec<String> {
    let t = |a: [f32; 3]| format!("({}, {}, {})", a[0], a[1], a[2]);
    match v.sdf {
        nerf::core::sdf::Sdf::Box {
            center,
            side_lengths,
        } => vec![
            format!("Box center: {}", t(center)),
            format!("Box side lengths: {}", t(side_lengths)),
        ],
        nerf::core::sdf::Sdf::Sphere { center, radius } => vec![
            format!("Sphere center: {}", t(center)),
            format!("Sphere radius: {radius}"),
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_checkpoint_flag_becomes_the_configured_path_verbatim() {
        for path in ["ck", "123", "null", "a b: #1", "x/[1,2]", "'q'\"", "yes"] {
            let o = checkpoint_path_override(Path::new(path)).unwrap();
            let config = Config::load("nerf_lego", &[o]).unwrap();
            assert_eq!(
                config.training.as_ref().and_then(|t| t.checkpoint()),
                Some(Path::new(path))
            );
        }
    }

    #[test]
    fn nerf_only_flags_are_named_for_an_sdf_fit() {
        let options = NerfTrainOptions {
            epochs: Some(2),
            overwrite: true,
            ..Default::default()
        };
        let config = Config::load("train_box", &[]).unwrap();
        let err = prepare_training(config, "train_box", &[], TrainJob::Sdf, None, &options)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("--epochs, --overwrite are for NeRF training"),
            "{err}"
        );
        let config = Config::load("train_box", &[]).unwrap();
        let plain = NerfTrainOptions::default();
        assert!(prepare_training(config, "train_box", &[], TrainJob::Sdf, None, &plain).is_ok());
    }
}
