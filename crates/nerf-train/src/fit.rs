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
//!
//! The log never holds a step the checkpoint does not: each step's line is kept in memory
//! and appended only after the checkpoint holding that step has been renamed into place. A
//! run killed (SIGKILL, a second Ctrl-C) or failing (a full disk) between checkpoints leaves
//! a log that ends at or before the checkpoint's step, and a failed checkpoint write ends the
//! run with one line, its temporary file removed.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use candle_core::Device;
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::camera_refinement::{auto_choice, write_poses, CameraRefinement, CameraRefinementMode};
use crate::model::{Optimizer, TrainModel};
use crate::schedule::{next_rays, time_learning_rate};
use crate::step::{learning_rate, logged_psnr, train_step, StepSettings, TrainRng};
use nerf_checkpoint::checkpoint::{self, CheckpointInfo};
use nerf_checkpoint::checkpoint_file::{self, CheckpointFormat};
use nerf_checkpoint::torch::{write_torch_checkpoint, TorchOptimizerInfo};
use nerf_field::trainable::FieldSpec;
use nerf_files::output::{open_append, remove_stale_temp_files, write_atomically};
use nerf_files::progress::Progress;
use nerf_render::field::Field;
use nerf_render::occupancy::{OccupancyGrid, OccupancyGridParams, CHECKPOINT_KEY};
use nerf_render::skipping::SampleCounts;
use nerf_scene::dataset::Dataset;

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
    /// Keep empty the cells around each training camera within this fraction of its distance
    /// from the origin ([`OccupancyGrid::clear_around_cameras`]; 0 = off).
    pub camera_clearance: f64,
    /// Keep a contracted grid's far shell occupied ([`OccupancyGrid::keep_far_shell`]): for
    /// photos whose far field is scene (a room, a street), not a backdrop or transparency.
    pub keep_far_shell: bool,
}

/// Everything a training run needs besides the data: the model's sizes, the schedule and the
/// per-step settings.
#[derive(Debug, Clone)]
pub struct TrainSettings {
    /// The model's kind and sizes (any field kind; see [`FieldSpec`]).
    pub model: Arc<dyn FieldSpec>,
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
    /// Adapt the rays per step to evaluate about this many samples ([`next_rays`]).
    pub samples_per_step: Option<usize>,
    /// The most rays an adapted step may take (each draws all its samples before skipping).
    pub max_rays: usize,
    /// Follow the time budget (`time_learning_rate`): with a time limit the run ignores
    /// `num_epochs` and decays the learning rate over the time; without, over the epochs.
    pub time_schedule: bool,
    /// Whether to refine the training cameras ([`crate::camera_refinement`]).
    pub camera_refinement: CameraRefinementMode,
    /// The sampler's depth range when the run narrowed it to an object (stored in the
    /// checkpoint for `eval`, `render` and `view`; [`nerf_scene::dataset::object_hull`]).
    pub sample_depths: Option<(f64, f64)>,
    /// The box the field and the occupancy grid were fitted to when the run found an object
    /// alone (stored in the checkpoint as [`CheckpointInfo::object_box`]).
    pub object_box: Option<[f64; 6]>,
}

/// Where a training run writes.
#[derive(Debug, Clone)]
pub struct TrainPaths {
    /// The safetensors checkpoint (model, Adam state, occupancy grid).
    pub checkpoint: PathBuf,
    /// The JSON-lines training log, one line per step, appended once the checkpoint holding
    /// the step is written.
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
pub(crate) type EvaluateHook<'a> = Box<dyn FnMut(&dyn Field) -> Result<CheckpointScore> + 'a>;

/// Renders a preview of the current model; returns the file it wrote.
pub(crate) type PreviewHook<'a> = Box<dyn FnMut(&dyn Field) -> Result<PathBuf> + 'a>;

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
pub(crate) fn rewind_log(log: &Path, last_step: u64) -> Result<()> {
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

/// An error naming the key when the progress a checkpoint records does not fit this run:
/// more rays per step than a step may take, or a position in an epoch past its `n_images`
/// steps (the file's own limits are checked when it is read).
fn check_resumable(
    info: &CheckpointInfo,
    settings: &TrainSettings,
    n_images: usize,
    path: &Path,
) -> Result<()> {
    let max_rays = settings.max_rays.max(64);
    if info.rays_per_step > max_rays {
        bail!(
            "checkpoint {}: metadata rays_per_step = {} is more than a step of this config may \
             take ({max_rays})",
            path.display(),
            info.rays_per_step
        );
    }
    if info.step_in_epoch >= n_images.max(1) {
        bail!(
            "checkpoint {}: metadata step_in_epoch = {} is past the {n_images} steps of an epoch \
             on this dataset",
            path.display(),
            info.step_in_epoch
        );
    }
    Ok(())
}

/// The model, optimiser and progress of a run: resumed from `paths.checkpoint` when
/// `settings.resume` and it exists, else freshly seeded (which is said on stderr).
fn start_or_resume(
    settings: &TrainSettings,
    paths: &TrainPaths,
    dataset: &Dataset,
    device: &Device,
) -> Result<(TrainModel, Optimizer, CheckpointInfo)> {
    let n_images = dataset.images.len();
    let (mut state, tensors, info) = if settings.resume && paths.checkpoint.is_file() {
        let resumed = TrainModel::from_checkpoint(&*settings.model, &paths.checkpoint, device)?;
        check_resumable(&resumed.info, settings, n_images, &paths.checkpoint)?;
        (resumed.model, resumed.tensors, resumed.info)
    } else {
        log::info!(
            "starting a fresh run (no checkpoint to resume at {}); writing it there",
            paths.checkpoint.display()
        );
        (
            TrainModel::seeded(&*settings.model, settings.seed, device)?,
            Default::default(),
            CheckpointInfo::default(),
        )
    };
    if let Some(schedule) = &settings.grid {
        // Every cell occupied until the first update probes them.
        state.occupancy = Some(OccupancyGrid::new(&schedule.grid)?);
    }
    let mut adam = Optimizer::new(&state, settings.lr)?;
    let from_sfm = dataset.normalisation.is_some_and(|n| n.from_sfm);
    let residual = dataset.normalisation.and_then(|n| n.sfm_residual);
    let refined = settings.camera_refinement.enabled(from_sfm, residual);
    if dataset.normalisation.is_some() && settings.camera_refinement == CameraRefinementMode::Auto {
        log::info!("{}", auto_choice(refined, from_sfm, residual));
    }
    if refined {
        let mut cameras = CameraRefinement::new(n_images, device)?;
        if info.adam_step > 0 && !cameras.load_state(&tensors)? {
            log::info!("the checkpoint holds no camera refinement: refining from zero");
        }
        log::info!("refining the {n_images} training cameras (training.camera_refinement)");
        adam.cameras = Some(cameras);
    }
    if info.adam_step > 0 {
        adam.load_state(&tensors, info.adam_step)?;
        if let (Some(schedule), Some(saved)) = (&settings.grid, tensors.get(CHECKPOINT_KEY)) {
            state.occupancy = Some(OccupancyGrid::from_tensor(&schedule.grid, saved)?);
        }
        log::info!(
            "resuming from {} at epoch {}{}",
            paths.checkpoint.display(),
            info.epoch,
            if info.step_in_epoch > 0 {
                format!(", step {} of it", info.step_in_epoch)
            } else {
                String::new()
            }
        );
    }
    Ok((state, adam, info))
}

/// Makes the run's directories and opens its log for appending, after dropping what a killed
/// run left behind (temporary files, log lines past the checkpoint). An error for a log path
/// that is a directory or device.
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
    // Refused before it is read: a directory, device or FIFO is not a log.
    drop(open_append(&paths.log).context("training log")?);
    rewind_log(&paths.log, step)?;
    // Opened again: the rewind may have replaced the file.
    open_append(&paths.log).context("training log")
}

/// Writes the model, optimiser state and occupancy grid atomically, in the format of the
/// file already there: a PyTorch checkpoint (the homework's, which this run resumed from)
/// stays one (model, Adam and epoch; it has no place for the grid), anything else is ours.
fn save(
    settings: &TrainSettings,
    paths: &TrainPaths,
    state: &TrainModel,
    info: &CheckpointInfo,
    adam: &Optimizer,
    device: &Device,
) -> Result<()> {
    let torch = paths.checkpoint.is_file()
        && checkpoint_file::detect_format(&paths.checkpoint).ok() == Some(CheckpointFormat::Torch);
    if torch {
        let mut tensors = checkpoint::model_tensors(state.varmap());
        tensors.extend(adam.state_tensors()?);
        let optimizer = TorchOptimizerInfo {
            lr: adam.lr(),
            initial_lr: settings.lr,
        };
        let tensors = tensors.into_iter().collect();
        let expected = state.field.parameter_shapes();
        return write_torch_checkpoint(
            &paths.checkpoint,
            &expected,
            &tensors,
            info.clone(),
            optimizer,
        );
    }
    let mut tensors = state.tensors(device)?;
    tensors.extend(adam.state_tensors()?);
    checkpoint::save(&paths.checkpoint, &tensors, info.clone())
}

/// One step's log line (`rays`: the step's rays).
fn log_step(
    log: &mut Vec<u8>,
    step: u64,
    epoch: usize,
    wall: f64,
    loss: f64,
    (samples, rays): (SampleCounts, usize),
) -> Result<()> {
    writeln!(
        log,
        "{{\"step\":{step},\"epoch\":{epoch},\"wall_s\":{wall:.3},\"loss\":{loss:.6e},\"psnr\":{:.3},\"evaluated\":{:.4},\"rays\":{rays}}}",
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
    state: TrainModel,
    adam: Optimizer,
    info: CheckpointInfo,
    log: File,
    /// Log lines of the steps since the last checkpoint: they reach the log only once a
    /// checkpoint holding those steps is in place, so the log never runs ahead of it.
    pending: Vec<u8>,
    bar: Progress,
    start: Instant,
    /// Seconds spent in hooks, left out of the logged training time.
    excluded: f64,
    wall_offset: f64,
    /// When the last plain progress line was printed (seconds since `start`).
    last_plain_line: f64,
    /// Training seconds this call may take.
    seconds: Option<f64>,
    /// Rays of the next step.
    rays: usize,
}

/// `1 h 02 min`, `3 min 05 s`, `12 s`.
fn format_duration(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match (s / 3600, (s % 3600) / 60, s % 60) {
        (0, 0, sec) => format!("{sec} s"),
        (0, m, sec) => format!("{m} min {sec:02} s"),
        (h, m, _) => format!("{h} h {m:02} min"),
    }
}

impl Run<'_> {
    /// The run's last checkpoint, the progress bar cleared, and the refined cameras' summary
    /// when they were refined: how every run ends (finished, stopped or out of time).
    fn finish(&mut self) -> Result<()> {
        self.checkpoint()?;
        self.bar.finish_and_clear();
        if let Some(cameras) = &self.adam.cameras {
            log::info!("{}", cameras.summary()?);
        }
        Ok(())
    }

    /// Writes the checkpoint of `self.info` (the model, optimiser and grid as they are now),
    /// then appends the log lines of the steps it holds.
    fn checkpoint(&mut self) -> Result<()> {
        save(
            self.settings,
            self.paths,
            &self.state,
            &self.info,
            &self.adam,
            self.device,
        )
        .with_context(|| {
            format!(
                "cannot write checkpoint {} (the run ends here; the last checkpoint and its log \
                 are intact)",
                self.paths.checkpoint.display()
            )
        })?;
        self.log
            .write_all(&self.pending)
            .and_then(|()| self.log.flush())
            .with_context(|| format!("cannot append to {}", self.paths.log.display()))?;
        self.pending.clear();
        if let Some(cameras) = &self.adam.cameras {
            let path = self.paths.checkpoint.with_extension("cameras.json");
            write_poses(cameras, &self.dataset.frames, &path)?;
        }
        Ok(())
    }

    fn wall(&self) -> f64 {
        self.wall_offset + self.start.elapsed().as_secs_f64() - self.excluded
    }

    /// The next step's rays, as the checkpoint keeps them (0 when they do not adapt).
    fn rays_to_save(&self) -> usize {
        match self.settings.samples_per_step {
            Some(_) => self.rays,
            None => 0,
        }
    }

    /// Whether the time limit of this call has been reached.
    fn out_of_time(&self) -> bool {
        self.seconds
            .is_some_and(|s| self.wall() - self.wall_offset >= s)
    }

    /// Updates the occupancy grid when the schedule says so.
    fn update_grid(&mut self, rng: &mut TrainRng) -> Result<()> {
        let Some(schedule) = &self.settings.grid else {
            return Ok(());
        };
        let step = self.adam.step_count();
        if !step.is_multiple_of(schedule.update_interval as u64) {
            return Ok(());
        }
        self.state.update_grid(
            step < schedule.warmup_steps as u64,
            schedule.decay as f32,
            rng,
            self.device,
        )
    }

    /// One epoch over the training images in a seeded random order, from step `first_step`
    /// with the random stream at `rng_word_pos` when resuming mid-epoch. Returns the mean loss
    /// over the steps taken, and `Some(steps taken in the epoch, stream position)` when a stop
    /// was requested before the epoch's end.
    fn epoch(
        &mut self,
        epoch: usize,
        first_step: usize,
        rng_word_pos: u128,
        stop: Option<&AtomicBool>,
    ) -> Result<(f64, Option<(usize, u128)>)> {
        let s = self.settings;
        self.adam.set_lr(learning_rate(
            s.lr,
            s.lr_scheduler_gamma,
            s.lr_scheduler_step_size,
            epoch,
        ));
        let mut rng =
            TrainRng::seed_from_u64(s.seed.wrapping_mul(1_000_003).wrapping_add(epoch as u64));
        let n_images = self.dataset.images.len();
        let mut order: Vec<usize> = (0..n_images).collect();
        order.shuffle(&mut rng);
        if first_step > 0 {
            rng.set_word_pos(rng_word_pos);
        }
        let mut epoch_loss = 0.0;
        for (k, &i) in order.iter().enumerate().skip(first_step) {
            let loss = self.step(epoch, i, &mut rng)?;
            epoch_loss += loss;
            let halt = stop.is_some_and(|f| f.load(Ordering::SeqCst)) || self.out_of_time();
            if halt && k + 1 < n_images {
                let taken = k + 1 - first_step;
                return Ok((epoch_loss / taken as f64, Some((k + 1, rng.get_word_pos()))));
            }
        }
        Ok((epoch_loss / (n_images - first_step).max(1) as f64, None))
    }

    /// One training step on image `image`: grid update, Adam step, log line, progress.
    fn step(&mut self, epoch: usize, image: usize, rng: &mut TrainRng) -> Result<f64> {
        self.update_grid(rng)?;
        if self.settings.time_schedule {
            let s = self.settings;
            let progress = match self.seconds {
                Some(limit) => (self.wall() - self.wall_offset) / limit.max(1e-9),
                None => {
                    let done = self.adam.step_count() as f64 / self.dataset.images.len() as f64;
                    done / s.num_epochs.max(1) as f64
                }
            };
            self.adam
                .set_lr(time_learning_rate(s.lr, s.lr_scheduler_gamma, progress));
            if let Some(limit) = self.seconds {
                // Steps so far plus those the time left holds at the pace so far.
                let done = self.bar.position().max(1);
                let spent = (self.wall() - self.wall_offset).max(1e-9);
                let left = (limit - spent).max(0.0) * done as f64 / spent;
                self.bar.set_length(done + left.round() as u64);
            }
        }
        let mut step_settings = self.settings.step.clone();
        step_settings.batch_size = self.rays;
        let (loss, samples) = train_step(
            &self.state,
            &step_settings,
            self.dataset,
            image,
            &mut self.adam,
            rng,
            self.device,
        )?;
        if !loss.is_finite() {
            bail!("training diverged at epoch {epoch}: loss is {loss}");
        }
        let wall = self.wall();
        let rays = self.rays;
        if let Some(target) = self.settings.samples_per_step {
            self.rays = next_rays(self.rays, samples.evaluated, target, self.settings.max_rays);
        }
        let step = self.adam.step_count();
        log_step(&mut self.pending, step, epoch, wall, loss, (samples, rays))?;
        self.progress(epoch, loss);
        Ok(loss)
    }

    /// The bar's message on a terminal; elsewhere a line every [`plain_progress_seconds`].
    fn progress(&mut self, epoch: usize, loss: f64) {
        let occupied = self
            .state
            .occupancy
            .as_ref()
            .map(|g| format!(" occupied {:.1}%", 100.0 * g.occupied_fraction()))
            .unwrap_or_default();
        let message = format!(
            "epoch {epoch} loss {loss:.4} psnr {:.2}{occupied}",
            logged_psnr(loss)
        );
        self.bar.inc(1);
        if !self.bar.is_hidden() {
            self.bar.set_message(message);
            return;
        }
        let now = self.start.elapsed().as_secs_f64();
        if now - self.last_plain_line >= nerf_files::progress::plain_line_seconds() {
            self.last_plain_line = now;
            let (done, total) = (self.bar.position(), self.bar.length());
            let mut eta = now / done.max(1) as f64 * total.saturating_sub(done) as f64;
            if let Some(limit) = self.seconds {
                // `--minutes` ends the run first.
                eta = eta.min(limit - (self.wall() - self.wall_offset));
            }
            log::info!(
                "step {} ({done}/{total} this run): {message}; eta {}",
                self.adam.step_count(),
                format_duration(eta)
            );
        }
    }

    /// The normalisation of the capture trained on, stored with the model so that every later
    /// use of its cameras puts them where training did.
    fn scene_transform(&self) -> Option<nerf_scene::dataset::SceneTransform> {
        self.dataset.normalisation.map(|n| n.applied)
    }

    /// For a capture, the orbit around its training cameras that `render` and `view` show
    /// the model from (`None` when the cameras give none: all on the z axis).
    fn capture_orbit(&self) -> Option<nerf_scene::dataset::CaptureOrbit> {
        self.dataset.normalisation?;
        nerf_scene::dataset::CaptureOrbit::from_frames(&self.dataset.frames).ok()
    }

    /// For a forward-facing capture, the spiral in front of its training cameras that
    /// `render` and `view` show the model from instead of the orbit (`None` for any other
    /// scene).
    fn capture_spiral(&self) -> Option<nerf_scene::dataset::CaptureSpiral> {
        let normalisation = self.dataset.normalisation?;
        nerf_scene::dataset::CaptureSpiral::from_frames(
            &self.dataset.frames,
            normalisation.depth_bounds,
        )
    }

    /// After epoch `epoch` (0-based): checkpoint, evaluation and preview as scheduled.
    fn after_epoch(&mut self, epoch: usize, mean_loss: f64, hooks: &mut Hooks) -> Result<()> {
        let s = self.settings;
        self.info = CheckpointInfo {
            epoch: epoch + 1,
            adam_step: self.adam.step_count(),
            wall_seconds: self.wall(),
            rays_per_step: self.rays_to_save(),
            scene_transform: self.scene_transform(),
            capture_orbit: self.capture_orbit(),
            capture_spiral: self.capture_spiral(),
            background: Some(self.settings.step.renderer.background),
            image_size: Some((self.dataset.width, self.dataset.height)),
            sample_depths: self.settings.sample_depths,
            object_box: self.settings.object_box,
            field_layout: self.state.field.layout(),
            ..CheckpointInfo::default()
        };
        if (epoch + 1).is_multiple_of(s.checkpoint_interval) {
            if let Some(evaluate) = hooks.evaluate.as_mut() {
                let t = Instant::now();
                let score = evaluate(&*self.state.render_field())?;
                writeln!(
                    self.pending,
                    "{{\"step\":{},\"epoch\":{},\"wall_s\":{:.3},\"test_psnr\":{:.3},\"test_views\":{}}}",
                    self.adam.step_count(),
                    epoch + 1,
                    self.info.wall_seconds,
                    score.psnr,
                    score.views
                )?;
                self.bar.println(&format!(
                    "epoch {}: test PSNR {:.2} dB on {} views at {:.1} min",
                    epoch + 1,
                    score.psnr,
                    score.views,
                    self.info.wall_seconds / 60.0
                ));
                self.excluded += t.elapsed().as_secs_f64();
            }
            self.checkpoint()?;
        }
        if (epoch + 1).is_multiple_of(s.render_interval) {
            if let Some(preview) = hooks.preview.as_mut() {
                let t = Instant::now();
                let written = preview(&*self.state.render_field())?;
                self.bar.println(&format!(
                    "epoch {}: mean train loss {mean_loss:.5}, wrote {}",
                    epoch + 1,
                    written.display()
                ));
                self.excluded += t.elapsed().as_secs_f64();
            }
        }
        Ok(())
    }
}

/// How much of the training a call to [`fit`] may do (both count this call only).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RunLimits {
    /// Stop after this many epochs.
    pub epochs: Option<usize>,
    /// Stop after the step that reaches this many seconds of training (hooks not counted).
    pub seconds: Option<f64>,
}

/// How a call to [`fit`] ended.
#[derive(Debug, Clone, PartialEq)]
pub enum FitOutcome {
    /// Every planned epoch ran, or the time limit was reached; the checkpoint holds the last
    /// step.
    Finished(CheckpointInfo),
    /// A stop was requested; the checkpoint holds the run up to the last whole step.
    Stopped(CheckpointInfo),
}

impl FitOutcome {
    /// What the checkpoint now holds.
    pub fn info(&self) -> CheckpointInfo {
        match self {
            FitOutcome::Finished(i) | FitOutcome::Stopped(i) => i.clone(),
        }
    }
}

/// Trains a NeRF on `dataset` (the training split). `limits` end the run early (after
/// writing a checkpoint) after that many epochs or seconds of training in this call; `stop`,
/// when it becomes true, ends it after the current step (after writing a checkpoint that a
/// later call resumes from exactly, mid-epoch if need be).
pub fn fit(
    settings: &TrainSettings,
    dataset: &Dataset,
    paths: &TrainPaths,
    limits: RunLimits,
    stop: Option<&AtomicBool>,
    mut hooks: Hooks,
    device: &Device,
) -> Result<FitOutcome> {
    nerf_core::allocator::ensure_allocator_tuned();
    let (mut state, adam, info) = start_or_resume(settings, paths, dataset, device)?;
    if let (Some(schedule), Some(grid)) = (&settings.grid, state.occupancy.as_mut()) {
        if schedule.keep_far_shell {
            grid.keep_far_shell();
        }
        if schedule.camera_clearance > 0.0 {
            let centres: Vec<[f64; 3]> = (dataset.frames.iter())
                .map(|f| f.camera.center().to_array())
                .collect();
            let kept = grid.clear_around_cameras(&centres, schedule.camera_clearance);
            log::info!(
                "occupancy grid: {kept} of {} cells kept empty around the {} training cameras",
                grid.n_cells(),
                centres.len()
            );
        }
    }
    // A run that follows its time budget trains for its time whatever num_epochs says
    // (up to the most epochs a checkpoint may record).
    let timed = settings.time_schedule && limits.seconds.is_some();
    let num_epochs = match timed {
        true => checkpoint::metadata_limits::EPOCHS as usize,
        false => settings.num_epochs,
    };
    if info.epoch >= num_epochs {
        // A run killed while rewriting its final checkpoint leaves a temporary file; nothing
        // else will clean it up here.
        remove_stale_temp_files(&paths.checkpoint);
        remove_stale_temp_files(&paths.log);
        log::info!("already trained for {} epochs", info.epoch);
        return Ok(FitOutcome::Finished(info));
    }
    let log = prepare_outputs(settings, paths, info.adam_step)?;
    let remaining = num_epochs - info.epoch;
    let planned = limits.epochs.map_or(remaining, |s| s.min(remaining));
    let n_images = dataset.images.len();
    let mut run = Run {
        settings,
        dataset,
        paths,
        device,
        state,
        adam,
        info: info.clone(),
        log,
        pending: Vec::new(),
        // Its own plain lines (step, loss, time left), not the bar's.
        // A timed run's length is re-estimated as it goes.
        bar: nerf_files::progress::Progress::new(
            match timed {
                true => n_images as u64,
                false => (planned * n_images - info.step_in_epoch) as u64,
            },
            "training",
        ),
        start: Instant::now(),
        excluded: 0.0,
        wall_offset: info.wall_seconds,
        last_plain_line: 0.0,
        seconds: limits.seconds,
        rays: match info.rays_per_step {
            0 => settings.step.batch_size,
            n => n,
        },
    };
    let first = info.epoch;
    let (mut first_step, mut word_pos) = (info.step_in_epoch, info.rng_word_pos);
    for epoch in first..first + planned {
        let (mean_loss, stopped) = run.epoch(epoch, first_step, word_pos, stop)?;
        (first_step, word_pos) = (0, 0);
        let signalled = stop.is_some_and(|f| f.load(Ordering::SeqCst));
        let ended = |info| match signalled {
            true => FitOutcome::Stopped(info),
            false => FitOutcome::Finished(info),
        };
        if let Some((step_in_epoch, rng_word_pos)) = stopped {
            run.info = CheckpointInfo {
                epoch,
                adam_step: run.adam.step_count(),
                wall_seconds: run.wall(),
                step_in_epoch,
                rng_word_pos,
                rays_per_step: run.rays_to_save(),
                scene_transform: run.scene_transform(),
                capture_orbit: run.capture_orbit(),
                capture_spiral: run.capture_spiral(),
                background: Some(run.settings.step.renderer.background),
                image_size: Some((run.dataset.width, run.dataset.height)),
                sample_depths: run.settings.sample_depths,
                object_box: run.settings.object_box,
                field_layout: run.state.field.layout(),
            };
            run.finish()?;
            return Ok(ended(run.info));
        }
        run.after_epoch(epoch, mean_loss, &mut hooks)?;
        if (signalled || run.out_of_time()) && epoch + 1 < first + planned {
            run.finish()?;
            return Ok(ended(run.info));
        }
    }
    run.finish()?;
    Ok(FitOutcome::Finished(run.info))
}
