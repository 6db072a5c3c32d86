//! Fitting an SDF volume's trainable parameters to images by gradient descent: the
//! homework's `train` (`main.py`, `type: train`, e.g. `train_box.yaml`).
//!
//! Each epoch visits the views in a random order; each step takes `batch_size` distinct random
//! pixels of one view, renders their rays (the sampler's fixed depths, as the homework's
//! sampler and the targets' own renders), and takes an Adam step on the mean squared colour
//! error. Gradients reach every variable of the model (the SDF volume's
//! `nerf_field::sdf::SdfModel`, or any [`TrainableField`]) through the renderer's
//! compositing and the SDF volume (fused kernels with backward passes on the CPU, tensor ops
//! elsewhere). After each step the parameters are held in their valid range
//! ([`TrainableField::constrain`]).

use std::time::Instant;

use anyhow::{bail, ensure, Result};
use candle_core::{Device, Tensor};
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::adam::Adam;
use nerf_core::camera::PerspectiveCamera;
use nerf_core::image::RgbImage;
use nerf_core::rays::{random_pixel_indices, Rays};
use nerf_field::trainable::TrainableField;
use nerf_files::progress::progress_bar;
use nerf_render::renderer::VolumeRenderer;
use nerf_render::sampler::StratifiedSampler;

/// One training view: a camera and the image it should see.
#[derive(Debug, Clone)]
pub struct SdfView {
    /// The camera.
    pub camera: PerspectiveCamera,
    /// The target image (its size is the rendered size).
    pub image: RgbImage,
}

/// How the fit runs.
#[derive(Debug, Clone)]
pub struct SdfFitSettings {
    /// Epochs: passes over all views, one step per view each.
    pub num_epochs: usize,
    /// Pixels (rays) per step.
    pub batch_size: usize,
    /// Adam's learning rate.
    pub lr: f64,
    /// Seeds the view order and the pixel choice.
    pub seed: u64,
    /// Samples along each ray.
    pub sampler: StratifiedSampler,
    /// Renders each batch.
    pub renderer: VolumeRenderer,
}

/// What a fit did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SdfFitReport {
    /// Adam steps taken.
    pub steps: u64,
    /// Loss (MSE) of the last step.
    pub final_loss: f64,
    /// Mean loss over the last epoch's steps.
    pub last_epoch_loss: f64,
    /// Wall-clock seconds of the loop.
    pub seconds: f64,
}

/// The rays of `pixels` of `view` and their target colours `(B, 3)`.
fn batch(view: &SdfView, pixels: &[usize], device: &Device) -> Result<(Rays, Tensor)> {
    let (w, h) = (view.image.width, view.image.height);
    let rays = Rays::for_pixels(&view.camera.into(), w, h, pixels, device)?;
    let data = &view.image.data;
    let target: Vec<f32> = pixels
        .iter()
        .flat_map(|&p| data[3 * p..3 * p + 3].iter().copied())
        .collect();
    Ok((rays, Tensor::from_vec(target, (pixels.len(), 3), device)?))
}

/// The mean squared error of the rendered `rays` against `target` `(B, 3)`, differentiable
/// in the model's variables: the model's fused render-and-loss kernel where it has one
/// ([`nerf_field::trainable::TrainingFastPaths::fused_mse`]; the SDF volume's on the CPU),
/// else the renderer and tensor ops.
pub fn batch_loss(
    model: &dyn TrainableField,
    settings: &SdfFitSettings,
    rays: &Rays,
    target: &Tensor,
) -> Result<Tensor> {
    let lengths = settings.sampler.lengths(rays, None)?;
    let white = settings.renderer.is_white();
    if let Some(fast) = model.fast_paths() {
        if let Some(loss) = fast.fused_mse(rays, &lengths, target, white)? {
            return Ok(loss);
        }
    }
    let field = model.training_field(0.0);
    let out = settings
        .renderer
        .render(&*field, &settings.sampler, rays, None)?;
    Ok(out.color.sub(target)?.sqr()?.mean_all()?)
}

/// Fits `model`'s variables to `views` in place; `on_step(epoch, step, loss)` is called after
/// every step (after the progress bar, which shows the loss, is updated).
pub fn fit_sdf(
    model: &dyn TrainableField,
    views: &[SdfView],
    settings: &SdfFitSettings,
    device: &Device,
    mut on_step: impl FnMut(usize, u64, f64),
) -> Result<SdfFitReport> {
    ensure!(!views.is_empty(), "no training views");
    ensure!(
        !model.varmap().all_vars().is_empty(),
        "nothing to train: no parameter of the SDF volume is trainable"
    );
    let mut adam = Adam::for_group(model.param_groups().dense, settings.lr)?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(settings.seed);
    let bar = progress_bar((settings.num_epochs * views.len()) as u64, "fitting");
    let start = Instant::now();
    let (mut final_loss, mut last_epoch_loss) = (f64::NAN, f64::NAN);
    for epoch in 0..settings.num_epochs {
        let mut order: Vec<usize> = (0..views.len()).collect();
        order.shuffle(&mut rng);
        let mut epoch_loss = 0.0;
        for &i in &order {
            let view = &views[i];
            let pixels = random_pixel_indices(
                view.image.width,
                view.image.height,
                settings.batch_size,
                &mut rng,
            );
            let (rays, target) = batch(view, &pixels, device)?;
            let loss = batch_loss(model, settings, &rays, &target)?;
            adam.step(&loss.backward()?)?;
            model.constrain()?;
            let loss = loss.to_scalar::<f32>()? as f64;
            if !loss.is_finite() {
                bail!("the fit diverged at epoch {epoch}: loss is {loss}");
            }
            epoch_loss += loss;
            final_loss = loss;
            bar.set_message(format!("epoch {epoch} loss {loss:.6}"));
            bar.inc(1);
            on_step(epoch, adam.step, loss);
        }
        last_epoch_loss = epoch_loss / views.len() as f64;
    }
    bar.finish_and_clear();
    Ok(SdfFitReport {
        steps: adam.step,
        final_loss,
        last_epoch_loss,
        seconds: start.elapsed().as_secs_f64(),
    })
}
