//! The homework's NeRF training loop with checkpoints and resume.
//!
//! Each iteration takes one training image (shuffled per epoch) and `batch_size` random pixels,
//! renders their rays with jittered stratified samples, and takes an Adam step on the MSE.
//! The learning rate is `lr · gamma^(epoch / step_size)` (the homework's LambdaLR). Every
//! `checkpoint_interval` epochs, and at the end, the model and Adam state are written atomically;
//! the [`Hooks`] can evaluate the model at each checkpoint and render previews (the logged wall
//! time leaves out both).
//! Randomness is seeded per epoch from `seed`, so a run resumed from epoch k continues exactly
//! as an uninterrupted run would.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use candle_core::Device;
use indicatif::ProgressBar;
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::field::nerf::{NerfField, NerfParams};
use crate::io::checkpoint::{self, CheckpointInfo};
use crate::io::checkpoint_file::{self, CheckpointFormat};
use crate::io::dataset::Dataset;
use crate::io::images::{remove_stale_temp_files, write_atomically};
use crate::io::progress::{print_above, progress_bar};
use crate::io::torch::{write_torch_checkpoint, TorchOptimizerInfo};
use crate::render::occupancy::{OccupancyGrid, OccupancyGridParams, CHECKPOINT_KEY};
use crate::render::skipping::SampleCounts;
use crate::train::adam::Adam;
use crate::train::state::{named_vars, NerfState};
use crate::train::step::{learning_rate, logged_psnr, train_step, StepSettings};

/// How training keeps an occupancy grid up to date (nerfacc's schedule).
#[derive(Debug, Clone, PartialEq)]
pub struct GridSchedule {
    /// The grid's extent, resolution and density threshold.
    pub grid: OccupancyGridParams,
    /// Update the grid every this many steps.
    pub update_interval: usize,
    /// Probe every cell at each update for the first this many steps.
    pub warmup_steps: usize,
    /// Decay of each cell's running density maximum per update.
    pub decay: f64,
}

/// Everything a training run needs besides the data: the model's sizes, the schedule and the
/// per-step settings.
#[derive(Debug, Clone)]
pub struct TrainSettings {
    /// The NeRF's sizes.
    pub model: NerfParams,
    /// What each step does (batch, rays, background, sampler, renderer).
    pub step: StepSettings,
    /// Seeds the initial weights and each epoch's random numbers.
    pub seed: u64,
    /// Epochs in all (a resumed run continues up to this).
    pub num_epochs: usize,
    /// Initial learning rate.
    pub lr: f64,
    /// Epochs per learning-rate decay step (`lr · gamma^(epoch / step_size)`).
    pub lr_scheduler_step_size: usize,
    /// Learning-rate decay factor per `lr_scheduler_step_size` epochs.
    pub lr_scheduler_gamma: f64,
    /// Write a checkpoint (and call [`Hooks::evaluate`]) every this many epochs.
    pub checkpoint_interval: usize,
    /// Call [`Hooks::preview`] every this many epochs.
    pub render_interval: usize,
    /// Continue from the checkpoint when one exists.
    pub resume: bool,
    /// The occupancy grid, when training uses one.
    pub grid: Option<GridSchedule>,
}

/// Where a training run writes.
#[derive(Debug, Clone)]
pub struct TrainPaths {
    /// The safetensors checkpoint (model, Adam state, occupancy grid).
    pub checkpoint: PathBuf,
    /// The JSON-lines training log, one line per step.
    pub log: PathBuf,
    /// Where previews are written.
    pub images: PathBuf,
}

/// A test score at a checkpoint: mean PSNR over `views` views.
#[derive(Debug, Clone, Copy)]
pub struct CheckpointScore {
    /// Mean PSNR in dB.
    pub psnr: f64,
    /// Views scored.
    pub views: usize,
}

/// Scores the current model at a checkpoint.
pub type EvaluateHook<'a> = Box<dyn FnMut(&NerfField) -> Result<CheckpointScore> + 'a>;

/// Renders a preview of the current model; returns the file it wrote.
pub type PreviewHook<'a> = Box<dyn FnMut(&NerfField) -> Result<PathBuf> + 'a>;

/// Callbacks of the loop; their time is left out of the logged training time.
#[derive(Default)]
pub struct Hooks<'a> {
    /// At every checkpoint: a test score of the current model, logged.
    pub evaluate: Option<EvaluateHook<'a>>,
    /// Every `render_interval` epochs: a preview of the current model.
    pub preview: Option<PreviewHook<'a>>,
}

/// Drops log lines of steps after `last_step` (written after the checkpoint a run resumes
/// from), so a resumed log has each step once. Rewritten atomically; a missing log is fine.
pub fn rewind_log(log: &Path, last_step: u64) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(log) else {
        return Ok(());
    };
    let step_of = |line: &str| -> Option<u64> {
        let v: serde_json::Value = serde_json::from_str(line).ok()?;
        v.get("step")?.as_u64()
    };
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| step_of(l).is_some_and(|s| s <= last_step))
        .collect();
    if kept.len() == text.lines().count() {
        return Ok(());
    }
    write_atomically(log, |w| {
        for line in kept {
            writeln!(w, "{line}")?;
        }
        Ok(())
    })
}

/// The model, optimiser and progress of a run: resumed from `paths.checkpoint` when
/// `settings.resume` and it exists, else freshly seeded.
fn start_or_resume(
    settings: &TrainSettings,
    paths: &TrainPaths,
    device: &Device,
) -> Result<(NerfState, Adam, CheckpointInfo)> {
    let (mut state, info) = if settings.resume && paths.checkpoint.is_file() {
        NerfState::from_checkpoint(&settings.model, &paths.checkpoint, device)?
    } else {
        (
            NerfState::seeded(&settings.model, settings.seed, device)?,
            CheckpointInfo::default(),
        )
    };
    if let Some(schedule) = &settings.grid {
        // Every cell occupied until the first update probes them.
        state.occupancy = Some(OccupancyGrid::new(&schedule.grid)?);
    }
    let mut adam = Adam::new(named_vars(&state.varmap), settings.lr)?;
    if info.epoch > 0 {
        let (tensors, _) = checkpoint_file::load(&paths.checkpoint, &settings.model, device)?;
        adam.load_state(&tensors, info.adam_step)?;
        if let (Some(schedule), Some(saved)) = (&settings.grid, tensors.get(CHECKPOINT_KEY)) {
            state.occupancy = Some(OccupancyGrid::from_tensor(&schedule.grid, saved)?);
        }
        eprintln!(
            "resuming from {} at epoch {}",
            paths.checkpoint.display(),
            info.epoch
        );
    }
    Ok((state, adam, info))
}

/// Makes the run's directories and opens its log for appending, after dropping what a killed
/// run left behind (temporary files, log lines past the checkpoint).
fn prepare_outputs(settings: &TrainSettings, paths: &TrainPaths, step: u64) -> Result<File> {
    if let Some(dir) = paths.log.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create checkpoint directory {}", dir.display()))?;
    }
    if settings.render_interval <= settings.num_epochs {
        // The preview's directory, made now so that a bad --out-dir fails before training.
        std::fs::create_dir_all(&paths.images).with_context(|| {
            format!("cannot create output directory {}", paths.images.display())
        })?;
    }
    remove_stale_temp_files(&paths.checkpoint);
    remove_stale_temp_files(&paths.log);
    rewind_log(&paths.log, step)?;
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&paths.log)
        .with_context(|| format!("cannot open training log {}", paths.log.display()))
}

/// Writes the model, Adam state and occupancy grid atomically, in the format of the file
/// already there: a PyTorch checkpoint (the homework's, which this run resumed from) stays
/// one (model, Adam and epoch; it has no place for the grid), anything else is ours.
fn save(
    settings: &TrainSettings,
    paths: &TrainPaths,
    state: &NerfState,
    info: &CheckpointInfo,
    adam: &Adam,
    device: &Device,
) -> Result<()> {
    let mut tensors = checkpoint::model_tensors(&state.varmap);
    tensors.extend(adam.state_tensors());
    let torch = paths.checkpoint.is_file()
        && checkpoint_file::detect_format(&paths.checkpoint).ok() == Some(CheckpointFormat::Torch);
    if torch {
        let optimizer = TorchOptimizerInfo {
            lr: adam.lr,
            initial_lr: settings.lr,
        };
        let tensors = tensors.into_iter().collect();
        return write_torch_checkpoint(
            &paths.checkpoint,
            &settings.model,
            &tensors,
            *info,
            optimizer,
        );
    }
    if let Some(grid) = &state.occupancy {
        tensors.push((CHECKPOINT_KEY.to_string(), grid.to_tensor(device)?));
    }
    checkpoint::save(&paths.checkpoint, &tensors, *info)
}

/// One step's log line.
fn log_step(
    log: &mut File,
    step: u64,
    epoch: usize,
    wall: f64,
    loss: f64,
    samples: SampleCounts,
) -> Result<()> {
    writeln!(
        log,
        "{{\"step\":{step},\"epoch\":{epoch},\"wall_s\":{wall:.3},\"loss\":{loss:.6e},\"psnr\":{:.3},\"evaluated\":{:.4}}}",
        logged_psnr(loss),
        samples.evaluated_fraction()
    )?;
    Ok(())
}

/// A running training loop: everything the epochs share.
struct Run<'a> {
    settings: &'a TrainSettings,
    dataset: &'a Dataset,
    paths: &'a TrainPaths,
    device: &'a Device,
    state: NerfState,
    adam: Adam,
    info: CheckpointInfo,
    log: File,
    bar: ProgressBar,
    start: Instant,
    /// Seconds spent in hooks, left out of the logged training time.
    excluded: f64,
    wall_offset: f64,
}

impl Run<'_> {
    fn wall(&self) -> f64 {
        self.wall_offset + self.start.elapsed().as_secs_f64() - self.excluded
    }

    /// Updates the occupancy grid when the schedule says so.
    fn update_grid(&mut self, rng: &mut rand::rngs::StdRng) -> Result<()> {
        let (Some(grid), Some(schedule)) = (&mut self.state.occupancy, &self.settings.grid) else {
            return Ok(());
        };
        if !self
            .adam
            .step
            .is_multiple_of(schedule.update_interval as u64)
        {
            return Ok(());
        }
        let model = self.state.model.detached();
        grid.update(
            &|p| model.density(p),
            self.adam.step < schedule.warmup_steps as u64,
            schedule.decay as f32,
            rng,
            self.device,
        )
    }

    /// One epoch over the training images in a seeded random order; returns the mean loss.
    fn epoch(&mut self, epoch: usize) -> Result<f64> {
        let s = self.settings;
        self.adam.lr = learning_rate(s.lr, s.lr_scheduler_gamma, s.lr_scheduler_step_size, epoch);
        let mut rng = rand::rngs::StdRng::seed_from_u64(
            s.seed.wrapping_mul(1_000_003).wrapping_add(epoch as u64),
        );
        let n_images = self.dataset.images.len();
        let mut order: Vec<usize> = (0..n_images).collect();
        order.shuffle(&mut rng);
        let mut epoch_loss = 0.0;
        for &i in &order {
            self.update_grid(&mut rng)?;
            let (loss, samples) = train_step(
                &self.state,
                &s.step,
                self.dataset,
                i,
                &mut self.adam,
                &mut rng,
                self.device,
            )?;
            if !loss.is_finite() {
                bail!("training diverged at epoch {epoch}: loss is {loss}");
            }
            epoch_loss += loss;
            let wall = self.wall();
            log_step(&mut self.log, self.adam.step, epoch, wall, loss, samples)?;
            let occupied = self
                .state
                .occupancy
                .as_ref()
                .map(|g| format!(" occupied {:.1}%", 100.0 * g.occupied_fraction()))
                .unwrap_or_default();
            self.bar.set_message(format!(
                "epoch {epoch} loss {loss:.4} psnr {:.2}{occupied}",
                logged_psnr(loss)
            ));
            self.bar.inc(1);
        }
        Ok(epoch_loss / n_images as f64)
    }

    /// After epoch `epoch` (0-based): checkpoint, evaluation and preview as scheduled.
    fn after_epoch(&mut self, epoch: usize, mean_loss: f64, hooks: &mut Hooks) -> Result<()> {
        let s = self.settings;
        self.info = CheckpointInfo {
            epoch: epoch + 1,
            adam_step: self.adam.step,
            wall_seconds: self.wall(),
        };
        if (epoch + 1).is_multiple_of(s.checkpoint_interval) {
            if let Some(evaluate) = hooks.evaluate.as_mut() {
                let t = Instant::now();
                let score = evaluate(&self.state.field())?;
                writeln!(
                    self.log,
                    "{{\"step\":{},\"epoch\":{},\"wall_s\":{:.3},\"test_psnr\":{:.3},\"test_views\":{}}}",
                    self.adam.step,
                    epoch + 1,
                    self.info.wall_seconds,
                    score.psnr,
                    score.views
                )?;
                print_above(
                    &self.bar,
                    &format!(
                        "epoch {}: test PSNR {:.2} dB on {} views",
                        epoch + 1,
                        score.psnr,
                        score.views
                    ),
                );
                self.excluded += t.elapsed().as_secs_f64();
            }
            save(
                s,
                self.paths,
                &self.state,
                &self.info,
                &self.adam,
                self.device,
            )?;
        }
        if (epoch + 1).is_multiple_of(s.render_interval) {
            if let Some(preview) = hooks.preview.as_mut() {
                let t = Instant::now();
                let written = preview(&self.state.field())?;
                print_above(
                    &self.bar,
                    &format!(
                        "epoch {}: mean train loss {mean_loss:.5}, wrote {}",
                        epoch + 1,
                        written.display()
                    ),
                );
                self.excluded += t.elapsed().as_secs_f64();
            }
        }
        Ok(())
    }
}

/// Trains a NeRF on `dataset` (the training split). `stop_after_epochs` ends the run early
/// (after writing a checkpoint) once that many epochs have been done in this call.
pub fn fit(
    settings: &TrainSettings,
    dataset: &Dataset,
    paths: &TrainPaths,
    stop_after_epochs: Option<usize>,
    mut hooks: Hooks,
    device: &Device,
) -> Result<CheckpointInfo> {
    let (state, adam, info) = start_or_resume(settings, paths, device)?;
    if info.epoch >= settings.num_epochs {
        eprintln!("already trained for {} epochs", info.epoch);
        return Ok(info);
    }
    let log = prepare_outputs(settings, paths, info.adam_step)?;
    let remaining = settings.num_epochs - info.epoch;
    let planned = stop_after_epochs.map_or(remaining, |s| s.min(remaining));
    let mut run = Run {
        settings,
        dataset,
        paths,
        device,
        state,
        adam,
        info,
        log,
        bar: progress_bar((planned * dataset.images.len()) as u64, "training"),
        start: Instant::now(),
        excluded: 0.0,
        wall_offset: info.wall_seconds,
    };
    let first = info.epoch;
    for epoch in first..first + planned {
        let mean_loss = run.epoch(epoch)?;
        run.after_epoch(epoch, mean_loss, &mut hooks)?;
    }
    save(settings, paths, &run.state, &run.info, &run.adam, device)?;
    run.bar.finish_and_clear();
    Ok(run.info)
}
