//! Which checkpoint a command reads or training writes: `--checkpoint`, the config's
//! `training.checkpoint_path`, or the shipped model, resolved by the one rule of
//! [`nerf_checkpoint::checkpoint_file`].

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::training::TrainingConfig;
use super::Config;
use nerf_checkpoint::checkpoint::CheckpointError;
use nerf_train::fit::TrainPaths;

/// The NeRF shipped with the project, the default of every command that loads a model when
/// neither `--checkpoint` nor the config's `training.checkpoint_path` names one.
pub(crate) const SHIPPED_CHECKPOINT: &str = "checkpoints/nerf_lego.safetensors";

/// The lego NeRF trained as the homework trains it (`nerf_lego`, dense sampling, no occupancy
/// grid): the shipped model for configs that render densely.
pub(crate) const HOMEWORK_CHECKPOINT: &str = "checkpoints/homework/nerf_lego.safetensors";

/// The shipped hash-grid lego model (the `lego_ngp` config's checkpoint).
pub const SHIPPED_NGP_CHECKPOINT: &str = "checkpoints/ngp_lego.safetensors";

impl Config {
    /// The checkpoint training reads and writes for `training.checkpoint_path`, by the one
    /// rule of [`nerf_checkpoint::checkpoint_file::resolve_for`] (a directory holding several
    /// checkpoints is an error; one holding none, or a new path, starts a fresh run), and its
    /// `.log.jsonl` beside it; previews go to `images`.
    pub fn train_paths(&self, images: &Path) -> Result<TrainPaths> {
        use nerf_checkpoint::checkpoint_file::{resolve_for, Purpose};
        let training = self.training()?;
        // Training never falls back to the shipped model: it needs a place of its own.
        let configured =
            TrainingConfig::required(training.checkpoint(), "checkpoint_path", "train a NeRF")?;
        let checkpoint = resolve_for(configured, &self.dataset_stem(), Purpose::Train)
            .context("training.checkpoint_path")?;
        Ok(TrainPaths {
            log: checkpoint.with_extension("log.jsonl"),
            checkpoint,
            images: images.to_path_buf(),
        })
    }

    /// The checkpoint a command reads — the one path for render, eval, bench, report, view and
    /// export: `given` (the `--checkpoint` option), else the config's
    /// `training.checkpoint_path`, else the shipped NeRF (`checkpoints/nerf_lego.safetensors`);
    /// a directory is resolved to the checkpoint it holds by
    /// [`nerf_checkpoint::checkpoint_file::resolve`] where it can be (where it cannot, the directory
    /// itself, whose [`Config::ensure_checkpoint`] error says why).
    pub fn checkpoint(&self, given: Option<&Path>) -> PathBuf {
        let configured = self.training.as_ref().and_then(|t| t.checkpoint());
        let path = given
            .or(configured)
            .unwrap_or(Path::new(SHIPPED_CHECKPOINT));
        nerf_checkpoint::checkpoint_file::resolve(path, &self.dataset_stem())
            .unwrap_or_else(|_| path.to_path_buf())
    }

    /// An error when `path` (from [`Config::checkpoint`]) is not a checkpoint file: for the
    /// config's own `training.checkpoint_path`, it names that key and what may be put there;
    /// for a directory, the one rule's error (none, or several, naming them).
    pub fn ensure_checkpoint(&self, path: &Path) -> Result<(), CheckpointError> {
        use nerf_checkpoint::checkpoint_file::{relative_note, resolve};
        if path.is_file() {
            return Ok(());
        }
        let configured = self.training.as_ref().and_then(|t| t.checkpoint());
        if let Some(c) = configured.filter(|c| !c.exists()) {
            if path == self.checkpoint(None) {
                let message = format!(
                    "checkpoint {} not found (training.checkpoint_path; put a checkpoint there, ours or the homework's torch.save file, or pass --checkpoint{}){}",
                    c.display(),
                    self.shipped_model_hint(),
                    relative_note(c)
                );
                return Err(CheckpointError::not_found(c, message));
            }
        }
        if path.is_dir() {
            resolve(path, &self.dataset_stem())?;
        }
        nerf_checkpoint::checkpoint_file::ensure_checkpoint_file(path)
    }

    /// Where a user without this config's checkpoint finds a shipped model that renders well:
    /// the hash-grid model for an `ngp` field; for the MLP, the shipped checkpoint when this
    /// config renders with an occupancy grid (as it was trained), else the densely trained
    /// [`HOMEWORK_CHECKPOINT`] or the `lego` config, since the shipped MLP rendered densely
    /// shows the ghost density its grid removes.
    fn shipped_model_hint(&self) -> String {
        match self.implicit_function.kind() {
            kind if kind == nerf_field::ngp::KIND => format!(
                "; the shipped hash-grid model is {SHIPPED_NGP_CHECKPOINT}, rendered by `nerf render --config lego_ngp` from the repository root"
            ),
            _ if self.occupancy_grid().is_some() => {
                format!(", e.g. the shipped {SHIPPED_CHECKPOINT}")
            }
            _ => format!(
                "; from the repository root, `nerf render --config lego` renders the shipped {SHIPPED_CHECKPOINT} best, with the occupancy grid it was trained with (this config, dense, would show ghost density), and --checkpoint {HOMEWORK_CHECKPOINT} is a model trained densely, as this config renders"
            ),
        }
    }
}
