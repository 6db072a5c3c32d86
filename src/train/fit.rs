//! `nerf train`: the homework's NeRF training loop with checkpoints and resume.
//!
//! Each iteration takes one training image (shuffled per epoch) and `batch_size` random pixels,
//! renders their rays with jittered stratified samples, and takes an Adam step on the MSE.
//! The learning rate is `lr · gamma^(epoch / step_size)` (the homework's LambdaLR). Every
//! `checkpoint_interval` epochs, and at the end, the model and Adam state are written atomically;
//! with `eval_views`, the test PSNR of the first views is logged at each checkpoint (the
//! logged wall time leaves out evaluation and progress renders).
//! Randomness is seeded per epoch from `seed`, so a run resumed from epoch k continues exactly
//! as an uninterrupted run would.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::app::config::{Config, ImplicitFunctionConfig, NerfConfig};
use crate::app::scene::{print_above, progress_bar};
use crate::core::rays::{random_pixel_indices, Rays};
use crate::field::nerf::Nerf;
use crate::io::checkpoint::{self, CheckpointInfo};
use crate::io::dataset::{Dataset, Split};
use crate::render::field::Field;
use crate::render::occupancy::OccupancyGrid;
use crate::train::adam::Adam;

/// A NeRF with its parameters.
pub struct NerfState {
    pub varmap: VarMap,
    pub model: Nerf,
    /// Where the model can have density, when the config uses an occupancy grid.
    pub occupancy: Option<OccupancyGrid>,
}

impl NerfState {
    /// A freshly initialised model: PyTorch's default `nn.Linear` init, U(−1/√fan_in,
    /// 1/√fan_in) for weights and biases, drawn from a generator seeded with `seed` (parameters
    /// in name order), so runs are reproducible.
    pub fn new(config: &NerfConfig, device: &Device) -> Result<Self> {
        Self::seeded(config, 0, device)
    }

    /// [`NerfState::new`] with an explicit seed.
    pub fn seeded(config: &NerfConfig, seed: u64, device: &Device) -> Result<Self> {
        use rand::Rng;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
        let model = Nerf::new(config, vb)?;
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        for (name, var) in named_vars(&varmap) {
            // fan_in is the weight's second dimension; a bias shares its layer's weight fan_in.
            let weight_name = name
                .strip_suffix(".bias")
                .map(|p| format!("{p}.weight"))
                .unwrap_or(name.clone());
            let fan_in = varmap.data().lock().expect("varmap lock")[&weight_name].dims()[1];
            let bound = 1.0 / (fan_in as f64).sqrt();
            let values: Vec<f32> = (0..var.elem_count())
                .map(|_| rng.random_range(-bound..bound) as f32)
                .collect();
            var.set(&Tensor::from_vec(values, var.shape(), device)?)?;
        }
        Ok(Self {
            varmap,
            model,
            occupancy: None,
        })
    }

    /// A model loaded from a checkpoint (names and shapes checked).
    pub fn from_checkpoint(
        config: &NerfConfig,
        path: &Path,
        device: &Device,
    ) -> Result<(Self, CheckpointInfo)> {
        let (tensors, info) = checkpoint::load(path, device)?;
        let state = Self::new(config, device)?;
        checkpoint::load_model_into(&state.varmap, &tensors, config, path)?;
        Ok((state, info))
    }

    /// A trained model for rendering with `config`: weights from the checkpoint, and the
    /// occupancy grid the config asks for (saved in the checkpoint, or built from the model).
    pub fn load(config: &Config, path: &Path, device: &Device) -> Result<(Self, CheckpointInfo)> {
        let nerf = nerf_config(config)?;
        let (tensors, info) = checkpoint::load(path, device)?;
        let mut state = Self::new(nerf, device)?;
        checkpoint::load_model_into(&state.varmap, &tensors, nerf, path)?;
        state.occupancy =
            crate::render::occupancy::grid_for_checkpoint(config, &tensors, &state.model, device)?;
        Ok((state, info))
    }

    /// The field for rendering: detached weights (no gradient graph), no density noise, and
    /// the occupancy grid if there is one.
    pub fn field(&self) -> Field {
        Field::Nerf {
            model: self.model.detached(),
            density_noise: 0.0,
            occupancy: self.occupancy.clone().map(Arc::new),
        }
    }
}

/// The NeRF section of a config, or an error naming the key.
pub fn nerf_config(config: &Config) -> Result<&NerfConfig> {
    match &config.implicit_function {
        ImplicitFunctionConfig::Nerf(n) => Ok(n),
        _ => bail!("implicit_function.type: this command needs nerf"),
    }
}

/// Learning rate after `epoch` epochs: `lr · gamma^(epoch / step_size)`.
pub fn learning_rate(lr: f64, gamma: f64, step_size: usize, epoch: usize) -> f64 {
    lr * gamma.powf(epoch as f64 / step_size as f64)
}

/// PSNR in dB of a training loss (an MSE of colours in [0, 1]), capped at 120 dB so that the
/// log never holds an infinity.
pub fn logged_psnr(mse: f64) -> f64 {
    crate::app::bench::psnr_from_mse(mse.max(1e-12))
}

/// Where a training run writes.
#[derive(Debug, Clone)]
pub struct TrainPaths {
    pub checkpoint: PathBuf,
    pub log: PathBuf,
    pub images: PathBuf,
}

impl TrainPaths {
    /// `<checkpoint_path>/nerf_<dataset>.safetensors` and `.log.jsonl` beside it.
    pub fn for_config(config: &Config, images: &Path) -> Result<Self> {
        let training = config
            .training
            .as_ref()
            .context("training: section missing from the config")?;
        let name = format!(
            "nerf_{}",
            config.data.dataset_name.as_deref().unwrap_or("scene")
        );
        Ok(Self {
            checkpoint: training.checkpoint_path.join(format!("{name}.safetensors")),
            log: training.checkpoint_path.join(format!("{name}.log.jsonl")),
            images: images.to_path_buf(),
        })
    }
}

/// A training batch: rays `(B, 3)`, their target colours `(B, 3)` on the dataset's
/// background, and their transparencies `(B, 1)` (`1 − alpha`; zeros when the dataset has
/// none). With
/// `rays_from_all_images`, `batch_size` random pixels of random training images; otherwise
/// `batch_size` random pixels of image `image_index` (the homework).
pub fn training_batch(
    dataset: &Dataset,
    batch_size: usize,
    rays_from_all_images: bool,
    image_index: usize,
    rng: &mut rand::rngs::StdRng,
    device: &Device,
) -> Result<(Rays, Tensor, Tensor)> {
    use rand::Rng;
    let (w, h) = (dataset.width, dataset.height);
    // (image, pixels) groups; rays of one camera are made together.
    let groups: Vec<(usize, Vec<usize>)> = if rays_from_all_images {
        let mut picks: Vec<(usize, usize)> = (0..batch_size)
            .map(|_| {
                (
                    rng.random_range(0..dataset.images.len()),
                    rng.random_range(0..w * h),
                )
            })
            .collect();
        picks.sort_unstable();
        let mut groups: Vec<(usize, Vec<usize>)> = Vec::new();
        for (image, pixel) in picks {
            match groups.last_mut() {
                Some((i, pixels)) if *i == image => pixels.push(pixel),
                _ => groups.push((image, vec![pixel])),
            }
        }
        groups
    } else {
        vec![(image_index, random_pixel_indices(w, h, batch_size, rng))]
    };
    let mut origins = Vec::with_capacity(groups.len());
    let mut directions = Vec::with_capacity(groups.len());
    let mut target: Vec<f32> = Vec::with_capacity(3 * batch_size);
    let mut transparency: Vec<f32> = Vec::with_capacity(batch_size);
    for (image, pixels) in &groups {
        let rays = Rays::for_pixels(&dataset.frames[*image].camera, w, h, pixels, device)?;
        origins.push(rays.origins);
        directions.push(rays.directions);
        let data = &dataset.images[*image].data;
        target.extend(
            pixels
                .iter()
                .flat_map(|&p| data[3 * p..3 * p + 3].iter().copied()),
        );
        let t = dataset.transparency.get(*image);
        transparency.extend(
            pixels
                .iter()
                .map(|&p| t.and_then(|t| t.get(p)).copied().unwrap_or(0.0)),
        );
    }
    let n = target.len() / 3;
    Ok((
        Rays {
            origins: Tensor::cat(&origins, 0)?,
            directions: Tensor::cat(&directions, 0)?,
        },
        Tensor::from_vec(target, (n, 3), device)?,
        Tensor::from_vec(transparency, (n, 1), device)?,
    ))
}

/// One optimisation step on a [`training_batch`]; returns the MSE and the sample counts.
#[allow(clippy::too_many_arguments)]
pub fn train_step(
    state: &NerfState,
    density_noise: f64,
    config: &Config,
    dataset: &Dataset,
    image_index: usize,
    adam: &mut Adam,
    rng: &mut rand::rngs::StdRng,
    device: &Device,
) -> Result<(f64, crate::render::skipping::SampleCounts)> {
    let training = config
        .training
        .as_ref()
        .context("training: section missing")?;
    let (rays, mut target, transparency) = training_batch(
        dataset,
        training.batch_size,
        training.rays_from_all_images,
        image_index,
        rng,
        device,
    )?;
    let field = Field::Nerf {
        model: state.model.clone(),
        density_noise,
        occupancy: state.occupancy.clone().map(Arc::new),
    };
    let mut renderer = config.renderer()?;
    let background = if training.random_background {
        // b ~ U(0, 1)³ per ray; the target moves from the dataset's background to b.
        use rand::Rng;
        let n = rays.len();
        let b: Vec<f32> = (0..3 * n).map(|_| rng.random::<f32>()).collect();
        let b = Tensor::from_vec(b, (n, 3), device)?;
        let dataset_bg = if renderer.white_background { 1.0 } else { 0.0 };
        target = target.add(&transparency.broadcast_mul(&b.affine(1.0, -dataset_bg)?)?)?;
        renderer.white_background = false;
        Some(b)
    } else {
        None
    };
    let out = renderer.render(&field, &config.sampler()?, &rays, Some(rng))?;
    let color = match &background {
        Some(b) => out
            .color
            .add(&out.opacity.affine(-1.0, 1.0)?.broadcast_mul(b)?)?,
        None => out.color,
    };
    let loss = color.sub(&target)?.sqr()?.mean_all()?;
    let grads = loss.backward()?;
    adam.step(&grads)?;
    Ok((loss.to_scalar::<f32>()? as f64, out.samples))
}

/// Named parameters for the optimiser, in a fixed order.
pub fn named_vars(varmap: &VarMap) -> Vec<(String, candle_core::Var)> {
    let data = varmap.data().lock().expect("varmap lock");
    let mut v: Vec<_> = data
        .iter()
        .map(|(k, var)| (k.clone(), var.clone()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
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
    crate::io::images::write_atomically(log, |w| {
        for line in kept {
            writeln!(w, "{line}")?;
        }
        Ok(())
    })
}

/// Runs `nerf train`. `stop_after_epochs` ends the run early (after writing a checkpoint) once
/// that many epochs have been done in this process.
pub fn train(
    config: &Config,
    data_dir: &Path,
    paths: &TrainPaths,
    stop_after_epochs: Option<usize>,
    device: &Device,
) -> Result<CheckpointInfo> {
    let training = config
        .training
        .clone()
        .context("training: section missing from the config")?;
    let nerf = nerf_config(config)?.clone();
    let (w, h) = config.image_size();
    let dataset = Dataset::load(
        data_dir,
        Split::Train,
        w,
        h,
        config.renderer.white_background,
    )?;
    let (mut state, mut info) = if training.resume && paths.checkpoint.is_file() {
        let (state, info) = NerfState::from_checkpoint(&nerf, &paths.checkpoint, device)?;
        (state, info)
    } else {
        (
            NerfState::seeded(&nerf, config.seed, device)?,
            CheckpointInfo::default(),
        )
    };
    let grid_settings = crate::render::occupancy::grid_settings(config);
    if let Some((settings, threshold)) = &grid_settings {
        // Every cell occupied until the first update probes them.
        state.occupancy = Some(OccupancyGrid::new(settings, *threshold)?);
    }
    let mut adam = Adam::new(named_vars(&state.varmap), training.lr)?;
    if info.epoch > 0 {
        let (tensors, _) = checkpoint::load(&paths.checkpoint, device)?;
        adam.load_state(&tensors, info.adam_step)?;
        if let (Some((settings, threshold)), Some(saved)) = (
            &grid_settings,
            tensors.get(crate::render::occupancy::CHECKPOINT_KEY),
        ) {
            state.occupancy = Some(OccupancyGrid::from_tensor(settings, *threshold, saved)?);
        }
        eprintln!(
            "resuming from {} at epoch {}",
            paths.checkpoint.display(),
            info.epoch
        );
    }
    if info.epoch >= training.num_epochs {
        eprintln!("already trained for {} epochs", info.epoch);
        return Ok(info);
    }
    if let Some(dir) = paths.log.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create checkpoint directory {}", dir.display()))?;
    }
    if training.render_interval <= training.num_epochs {
        // The progress GIFs' directory, made now so that a bad --out-dir fails before training.
        std::fs::create_dir_all(&paths.images).with_context(|| {
            format!("cannot create output directory {}", paths.images.display())
        })?;
    }
    // A run killed while writing leaves its temporary file behind; the files themselves are
    // whole (written atomically).
    crate::io::images::remove_stale_temp_files(&paths.checkpoint);
    crate::io::images::remove_stale_temp_files(&paths.log);
    rewind_log(&paths.log, info.adam_step)?;
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&paths.log)
        .with_context(|| format!("cannot open training log {}", paths.log.display()))?;
    let n_images = dataset.images.len();
    let remaining = training.num_epochs - info.epoch;
    let planned = stop_after_epochs.map_or(remaining, |s| s.min(remaining));
    let bar = progress_bar((planned * n_images) as u64, "training");
    let start = Instant::now();
    // Seconds spent on evaluation and progress renders, left out of the logged training time.
    let mut excluded = 0.0;
    let test_views = if training.eval_views > 0 {
        match Dataset::load(
            data_dir,
            Split::Test,
            w,
            h,
            config.renderer.white_background,
        ) {
            Ok(d) => Some(d),
            Err(e) => {
                print_above(&bar, &format!("warning: no test-PSNR logging: {e:#}"));
                None
            }
        }
    } else {
        None
    };
    let wall_offset = info.wall_seconds;
    let save = |state: &NerfState, info: &CheckpointInfo, adam: &Adam| -> Result<()> {
        let mut tensors = checkpoint::model_tensors(&state.varmap);
        tensors.extend(adam.state_tensors());
        if let Some(grid) = &state.occupancy {
            tensors.push((
                crate::render::occupancy::CHECKPOINT_KEY.to_string(),
                grid.to_tensor(device)?,
            ));
        }
        checkpoint::save(&paths.checkpoint, &tensors, *info)
    };
    for epoch in info.epoch..info.epoch + planned {
        adam.lr = learning_rate(
            training.lr,
            training.lr_scheduler_gamma,
            training.lr_scheduler_step_size,
            epoch,
        );
        let mut rng = rand::rngs::StdRng::seed_from_u64(
            config
                .seed
                .wrapping_mul(1_000_003)
                .wrapping_add(epoch as u64),
        );
        let mut order: Vec<usize> = (0..n_images).collect();
        order.shuffle(&mut rng);
        let mut epoch_loss = 0.0;
        for &i in &order {
            if let (Some(grid), Some((settings, _))) = (&mut state.occupancy, &grid_settings) {
                if adam.step % settings.update_interval as u64 == 0 {
                    grid.update(
                        &state.model.detached(),
                        adam.step < settings.warmup_steps as u64,
                        settings.decay as f32,
                        &mut rng,
                        device,
                    )?;
                }
            }
            let (loss, samples) = train_step(
                &state,
                nerf.density_noise_std,
                config,
                &dataset,
                i,
                &mut adam,
                &mut rng,
                device,
            )?;
            if !loss.is_finite() {
                bail!("training diverged at epoch {epoch}: loss is {loss}");
            }
            epoch_loss += loss;
            let wall = wall_offset + start.elapsed().as_secs_f64() - excluded;
            writeln!(
                log,
                "{{\"step\":{},\"epoch\":{},\"wall_s\":{:.3},\"loss\":{:.6e},\"psnr\":{:.3},\"evaluated\":{:.4}}}",
                adam.step,
                epoch,
                wall,
                loss,
                logged_psnr(loss),
                samples.evaluated as f64 / samples.total.max(1) as f64
            )?;
            let occupied = state
                .occupancy
                .as_ref()
                .map(|g| format!(" occupied {:.1}%", 100.0 * g.occupied_fraction()))
                .unwrap_or_default();
            bar.set_message(format!(
                "epoch {epoch} loss {loss:.4} psnr {:.2}{occupied}",
                logged_psnr(loss)
            ));
            bar.inc(1);
        }
        info = CheckpointInfo {
            epoch: epoch + 1,
            adam_step: adam.step,
            wall_seconds: wall_offset + start.elapsed().as_secs_f64() - excluded,
        };
        if (epoch + 1) % training.checkpoint_interval == 0 {
            if let Some(test) = &test_views {
                let t = Instant::now();
                let report = crate::eval::evaluate::evaluate(
                    config,
                    &state.field(),
                    test,
                    Split::Test,
                    None,
                    Some(training.eval_views),
                    device,
                )?;
                writeln!(
                    log,
                    "{{\"step\":{},\"epoch\":{},\"wall_s\":{:.3},\"test_psnr\":{:.3},\"test_views\":{}}}",
                    adam.step,
                    epoch + 1,
                    info.wall_seconds,
                    report.mean_psnr,
                    report.views.len()
                )?;
                print_above(
                    &bar,
                    &format!(
                        "epoch {}: test PSNR {:.2} dB on {} views",
                        epoch + 1,
                        report.mean_psnr,
                        report.views.len()
                    ),
                );
                excluded += t.elapsed().as_secs_f64();
            }
            save(&state, &info, &adam)?;
        }
        if (epoch + 1) % training.render_interval == 0 {
            let t = Instant::now();
            let gif = crate::app::scene::render_nerf_gif(
                config,
                &state.field(),
                &paths.images.join("render_nerf_training.gif"),
                device,
            )?;
            print_above(
                &bar,
                &format!(
                    "epoch {}: mean train loss {:.5}, wrote {}",
                    epoch + 1,
                    epoch_loss / n_images as f64,
                    gif.display()
                ),
            );
            excluded += t.elapsed().as_secs_f64();
        }
    }
    save(&state, &info, &adam)?;
    bar.finish_and_clear();
    Ok(info)
}
