//! The `training` section, and the settings of the jobs that train: an SDF fit and NeRF
//! training.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use serde::Deserialize;

use super::Config;
use nerf_train::camera_refinement::CameraRefinementMode;
use nerf_train::fit::TrainSettings;
use nerf_train::fit_sdf::SdfFitSettings;
use nerf_train::step::StepSettings;

/// `training`, as written: every key may be missing, since each job reads only its own
/// (`train_nerf` all of the homework's, `train` the first three, `render_nerf` only the
/// checkpoint). A job asks for a key with [`TrainingConfig::required`], which names a missing
/// one. The homework's code has no defaults for these keys.
#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TrainingConfig {
    /// Epochs to train (`training.num_epochs`): one step per training image (NeRF) or per
    /// training camera (the box fit) each.
    pub num_epochs: Option<usize>,
    /// Rays per training step (`training.batch_size`).
    pub batch_size: Option<usize>,
    /// Initial Adam learning rate (`training.lr`).
    pub lr: Option<f64>,
    /// Epochs between learning-rate decays (`training.lr_scheduler_step_size`).
    pub lr_scheduler_step_size: Option<usize>,
    /// Learning-rate factor per `lr_scheduler_step_size` epochs (`training.lr_scheduler_gamma`).
    pub lr_scheduler_gamma: Option<f64>,
    /// The checkpoint (`training.checkpoint_path`): a checkpoint file (ours or a PyTorch
    /// one), or a directory holding `nerf_<dataset_name>.safetensors` (see
    /// `crate::checkpoint_paths`). An empty string means none, as in the homework.
    pub checkpoint_path: Option<PathBuf>,
    /// Epochs between checkpoints (`training.checkpoint_interval`).
    pub checkpoint_interval: Option<usize>,
    /// Continue from the checkpoint when one exists (`training.resume`, default false).
    pub resume: bool,
    /// Epochs between preview renders (`training.render_interval`).
    pub render_interval: Option<usize>,
    /// Extension: draw each batch's rays from all training images instead of one image per
    /// step (the homework's scheme, the default).
    pub rays_from_all_images: bool,
    /// Extension: composite each training ray onto a random colour (prediction and target
    /// alike) instead of the fixed background, so that density where the object is
    /// transparent costs loss even when its colour matches the background.
    pub random_background: bool,
    /// Extension: at every checkpoint, log the test PSNR over the first this many test views
    /// (0 = off).
    pub eval_views: usize,
    /// Extension: adapt the rays per step so that each step evaluates about this many samples
    /// (instant-ngp's scheme: many rays once the occupancy grid and early termination leave
    /// few samples per ray); `batch_size` is then the first step's rays. Unset: fixed.
    pub samples_per_step: Option<usize>,
    /// Extension, `training.schedule`: `epochs` (the homework's: `num_epochs`, the learning
    /// rate decayed by `lr_scheduler_gamma` every `lr_scheduler_step_size` epochs) or `time`
    /// (with `--minutes` the run trains for that time whatever `num_epochs` says, and the
    /// learning rate falls smoothly from `lr` to `lr · lr_scheduler_gamma` over the time;
    /// without, over the `num_epochs`).
    pub schedule: Schedule,
    /// Extension: weight of mip-NeRF 360's distortion loss, each batch's mean, added to the
    /// MSE (0 = off, the default; nerfacto uses 0.002). Needs a `stratified` or
    /// `depth_then_disparity` sampler.
    pub distortion_loss: f64,
    /// Extension: refine each training camera's pose with the field
    /// ([`nerf_train::camera_refinement`]): `off` (the default),
    /// `on`, or `auto` (on for a COLMAP model whose points reproject
    /// `nerf_train::camera_refinement::AUTO_REFINE_RESIDUAL_PX` or more off).
    pub camera_refinement: CameraRefinementMode,
}

/// `training.schedule` (extension): what the run's length and learning-rate decay follow.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// Epochs, as the homework.
    #[default]
    Epochs,
    /// The time budget of `--minutes` (else the epochs).
    Time,
}

impl TrainingConfig {
    /// The value of `training.<key>`, or an error naming the key and the job that needs it.
    pub fn required<T: Copy>(value: Option<T>, key: &str, job: &str) -> Result<T> {
        value.ok_or_else(|| anyhow!("training.{key}: missing (needed to {job})"))
    }

    /// The checkpoint path, `None` when missing or empty (the homework's "no checkpoint").
    pub fn checkpoint(&self) -> Option<&Path> {
        self.checkpoint_path
            .as_deref()
            .filter(|p| !p.as_os_str().is_empty())
    }
}

impl Config {
    /// The `training` section, or an error saying it is missing.
    pub fn training(&self) -> Result<&TrainingConfig> {
        self.training
            .as_ref()
            .context("training: section missing from the config")
    }

    /// The settings of an SDF fit (`type: train`): `training.num_epochs`, `batch_size` and
    /// `lr` (an error names a missing one), the seed, sampler and renderer.
    pub fn sdf_fit_settings(&self) -> Result<SdfFitSettings> {
        let t = self.training()?;
        let job = "fit an SDF volume (type: train)";
        Ok(SdfFitSettings {
            num_epochs: TrainingConfig::required(t.num_epochs, "num_epochs", job)?,
            batch_size: TrainingConfig::required(t.batch_size, "batch_size", job)?,
            lr: TrainingConfig::required(t.lr, "lr", job)?,
            seed: self.seed,
            sampler: self.stratified_sampler()?,
            renderer: self.renderer()?,
        })
    }

    /// Everything the NeRF training loop needs from the config; an error names a missing
    /// `training` key.
    pub fn train_settings(&self) -> Result<TrainSettings> {
        let t = self.training()?;
        let (model, density_noise) = (self.field_spec()?, self.density_noise());
        let job = "train a NeRF";
        let req = |v: Option<usize>, key: &str| TrainingConfig::required(v, key, job);
        Ok(TrainSettings {
            model,
            step: StepSettings {
                batch_size: req(t.batch_size, "batch_size")?,
                rays_from_all_images: t.rays_from_all_images,
                random_background: t.random_background,
                density_noise,
                sampler: self.sampler()?,
                renderer: self.renderer()?,
                distortion_loss: t.distortion_loss,
            },
            seed: self.seed,
            num_epochs: req(t.num_epochs, "num_epochs")?,
            lr: TrainingConfig::required(t.lr, "lr", job)?,
            lr_scheduler_step_size: req(t.lr_scheduler_step_size, "lr_scheduler_step_size")?,
            lr_scheduler_gamma: TrainingConfig::required(
                t.lr_scheduler_gamma,
                "lr_scheduler_gamma",
                job,
            )?,
            checkpoint_interval: req(t.checkpoint_interval, "checkpoint_interval")?,
            render_interval: req(t.render_interval, "render_interval")?,
            resume: t.resume,
            grid: self.grid_schedule(),
            samples_per_step: t.samples_per_step,
            max_rays: self.max_rays_per_step()?,
            time_schedule: t.schedule == Schedule::Time,
            camera_refinement: t.camera_refinement,
            sample_depths: None,
            object_box: None,
        })
    }

    /// The most rays an adapted training step may take: those whose drawn samples fit
    /// [`limits::DRAWN_SAMPLES`] when the renderer skips samples (an occupancy grid or early
    /// termination; only evaluated samples hold activations), else [`limits::BATCH_SAMPLES`].
    fn max_rays_per_step(&self) -> Result<usize> {
        use crate::limits;
        let skips = self.grid_schedule().is_some() || self.renderer()?.early_termination > 0.0;
        let budget = if skips {
            limits::DRAWN_SAMPLES
        } else {
            limits::BATCH_SAMPLES
        };
        Ok(budget / self.sampler.drawn_per_ray().max(1))
    }
}
