//! One training step (NeRF MLP or hash grid): the learning-rate schedule, a batch of rays with their targets,
//! and an Adam step on the MSE.

use anyhow::Result;
use candle_core::backprop::GradStore;
use candle_core::{Device, Tensor};

use crate::camera_refinement::{tracks_cameras, CameraRefinement};
use crate::model::{Optimizer, TrainModel};
use nerf_core::metrics::psnr_from_mse;
use nerf_core::rays::{random_pixel_indices, Rays};
use nerf_field::fused_step::FusedBatch;
use nerf_render::ray_sampler::RaySampler;
use nerf_render::renderer::VolumeRenderer;
use nerf_render::skipping::SampleCounts;
use nerf_scene::dataset::Dataset;

/// The training loop's random generator: ChaCha12, the generator behind
/// `rand::rngs::StdRng` (the same stream for the same seed), whose position can be saved and
/// restored (`get_word_pos` / `set_word_pos`).
pub type TrainRng = rand_chacha::ChaCha12Rng;

/// Learning rate after `epoch` epochs: `lr · gamma^(epoch / step_size)`.
pub(crate) fn learning_rate(lr: f64, gamma: f64, step_size: usize, epoch: usize) -> f64 {
    lr * gamma.powf(epoch as f64 / step_size as f64)
}

/// PSNR in dB of a training loss (an MSE of colours in [0, 1]), capped at 120 dB so that the
/// log never holds an infinity.
pub(crate) fn logged_psnr(mse: f64) -> f64 {
    psnr_from_mse(mse.max(1e-12))
}

/// A training batch: rays `(B, 3)` (each with the index of its image as its camera), their target colours `(B, 3)` on the dataset's
/// background, and their transparencies `(B, 1)` (`1 − alpha`; zeros when the dataset has
/// none). With
/// `rays_from_all_images`, `batch_size` random pixels of random training images; otherwise
/// `batch_size` random pixels of image `image_index` (the homework). Pixels a frame's mask
/// ignores are never drawn: with masks, the pixels are drawn uniformly from the used pixels
/// of all images (of image `image_index`).
pub fn training_batch(
    dataset: &Dataset,
    batch_size: usize,
    rays_from_all_images: bool,
    image_index: usize,
    rng: &mut TrainRng,
    device: &Device,
) -> Result<(Rays, Tensor, Tensor)> {
    let all = rays_from_all_images;
    training_batch_refined(dataset, (batch_size, all), image_index, None, rng, device)
}

/// [`training_batch`] (`(batch_size, rays_from_all_images)`) with each ray moved by its
/// camera's correction when `cameras` are refined
/// ([`crate::camera_refinement`]; the rays are then tracked by autograd).
pub(crate) fn training_batch_refined(
    dataset: &Dataset,
    (batch_size, rays_from_all_images): (usize, bool),
    image_index: usize,
    cameras: Option<&CameraRefinement>,
    rng: &mut TrainRng,
    device: &Device,
) -> Result<(Rays, Tensor, Tensor)> {
    use rand::Rng;
    let (w, h) = (dataset.width, dataset.height);
    // (image, pixels) groups; rays of one camera are made together.
    let groups: Vec<(usize, Vec<usize>)> = if rays_from_all_images {
        let mut picks: Vec<(usize, usize)> = if dataset.masks.is_empty() {
            (0..batch_size)
                .map(|_| {
                    (
                        rng.random_range(0..dataset.images.len()),
                        rng.random_range(0..w * h),
                    )
                })
                .collect()
        } else {
            used_pixel_picks(dataset, batch_size, rng)
        };
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
        let pixels = match dataset.mask(image_index) {
            None => random_pixel_indices(w, h, batch_size, rng),
            Some(mask) => {
                let used = mask.used_pixels();
                rand::seq::index::sample(rng, used.len(), batch_size.min(used.len()))
                    .into_iter()
                    .map(|k| used[k] as usize)
                    .collect()
            }
        };
        vec![(image_index, pixels)]
    };
    let mut origins = Vec::with_capacity(groups.len());
    let mut directions = Vec::with_capacity(groups.len());
    let mut camera_index: Vec<u32> = Vec::with_capacity(batch_size);
    let mut target: Vec<f32> = Vec::with_capacity(3 * batch_size);
    let mut transparency: Vec<f32> = Vec::with_capacity(batch_size);
    for (image, pixels) in &groups {
        let rays = Rays::for_pixels(&dataset.frames[*image].camera, w, h, pixels, device)?;
        origins.push(rays.origins);
        directions.push(rays.directions);
        camera_index.extend(std::iter::repeat_n(*image as u32, pixels.len()));
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
    let mut rays = Rays {
        origins: Tensor::cat(&origins, 0)?,
        directions: Tensor::cat(&directions, 0)?,
        camera_index: None,
    };
    if let Some(cameras) = cameras {
        rays = cameras.apply(&rays, &camera_index)?;
    }
    rays.camera_index = Some(Tensor::from_vec(camera_index, n, device)?);
    Ok((
        rays,
        Tensor::from_vec(target, (n, 3), device)?,
        Tensor::from_vec(transparency, (n, 1), device)?,
    ))
}

/// `n` `(image, pixel)` pairs drawn uniformly (with replacement) from the used pixels of all
/// images: every pixel of an image without a mask, the used ones of a masked image.
fn used_pixel_picks(dataset: &Dataset, n: usize, rng: &mut TrainRng) -> Vec<(usize, usize)> {
    use rand::Rng;
    let all = dataset.width * dataset.height;
    // ends[i]: used pixels in images 0..=i.
    let ends: Vec<usize> = (0..dataset.images.len())
        .scan(0, |total, i| {
            *total += dataset.mask(i).map_or(all, |m| m.used_pixels().len());
            Some(*total)
        })
        .collect();
    let total = ends.last().copied().unwrap_or(0);
    (0..n)
        .map(|_| {
            let r = rng.random_range(0..total);
            let image = ends.partition_point(|&end| end <= r);
            let k = r - if image == 0 { 0 } else { ends[image - 1] };
            let pixel = dataset
                .mask(image)
                .map_or(k, |m| m.used_pixels()[k] as usize);
            (image, pixel)
        })
        .collect()
}

/// What one training step does, besides the model: the batch, how rays are drawn and
/// rendered, and the background.
#[derive(Debug, Clone)]
pub struct StepSettings {
    /// Rays per step.
    pub batch_size: usize,
    /// Draw the batch from all training images (else from one image per step, the homework).
    pub rays_from_all_images: bool,
    /// Composite each ray onto a random colour, prediction and target alike.
    pub random_background: bool,
    /// Standard deviation of the density noise added before the density ReLU (0 = off).
    pub density_noise: f64,
    /// Draws each ray's samples (jittered in training).
    pub sampler: std::sync::Arc<dyn RaySampler>,
    /// Renders the batch; its background is the dataset's unless `random_background`.
    pub renderer: VolumeRenderer,
    /// Weight of mip-NeRF 360's distortion loss, the batch's mean, added to the MSE
    /// (`training.distortion_loss`; 0 = off).
    pub distortion_loss: f64,
}

/// One optimisation step on a [`training_batch`] (on the MSE, plus the distortion loss when
/// weighted); returns the MSE and the sample counts. The forward and backward passes are the
/// field's fused step where it has one for these settings (`fused_step_applies`), else
/// autograd's (`graph_gradients`).
pub fn train_step(
    model: &TrainModel,
    settings: &StepSettings,
    dataset: &Dataset,
    image_index: usize,
    optimizer: &mut Optimizer,
    rng: &mut TrainRng,
    device: &Device,
) -> Result<(f64, SampleCounts)> {
    let (mut rays, target, transparency) = training_batch_refined(
        dataset,
        (settings.batch_size, settings.rays_from_all_images),
        image_index,
        optimizer.cameras.as_ref(),
        rng,
        device,
    )?;
    if optimizer.cameras.is_some() && !tracks_cameras(optimizer.step_count()) {
        // Moved by the corrections, but no camera gradient this step.
        rays.origins = rays.origins.detach();
        rays.directions = rays.directions.detach();
    }
    let field = model.training_field(settings.density_noise);
    let background = step_background(settings, &target, &transparency, rng)?;
    // Rays tracked for camera refinement need autograd; moved but untracked ones do not.
    let rays_tracked = rays.origins.track_op() || rays.directions.track_op();
    let fused = !rays_tracked && fused_step_applies(settings, &*field);
    let step = match fused {
        true => fused_gradients(model, settings, &*field, &rays, &background, rng)?,
        false => None,
    };
    let step = match step {
        Some(step) => step,
        None => graph_gradients(&*field, settings, &rays, &background, rng)?,
    };
    optimizer.step(&step.grads)?;
    Ok((step.mse, step.samples))
}

/// A batch's targets and the colour behind its rays: with a random background, `b ~ U(0, 1)³`
/// per ray and each target moved from the dataset's background to `b` by its transparency;
/// else the targets as they are, in front of the renderer's background.
pub struct StepBackground {
    /// Target colours `(N, 3)`.
    pub target: Tensor,
    /// `(N, 3)` the random background, or `None`: the renderer's own.
    pub random: Option<Tensor>,
}

/// The [`StepBackground`] of a batch's `target` `(N, 3)` and `transparency` `(N, 1)`: draws
/// the random background from `rng` when `settings` ask for one.
pub(crate) fn step_background(
    settings: &StepSettings,
    target: &Tensor,
    transparency: &Tensor,
    rng: &mut TrainRng,
) -> Result<StepBackground> {
    if !settings.random_background {
        return Ok(StepBackground {
            target: target.clone(),
            random: None,
        });
    }
    use rand::Rng;
    let n = target.dim(0)?;
    let device = target.device();
    let b: Vec<f32> = (0..3 * n).map(|_| rng.random::<f32>()).collect();
    let b = Tensor::from_vec(b, (n, 3), device)?;
    let dataset_bg = Tensor::new(&[settings.renderer.background], device)?;
    let target = target.add(&transparency.broadcast_mul(&b.broadcast_sub(&dataset_bg)?)?)?;
    Ok(StepBackground {
        target,
        random: Some(b),
    })
}

/// One step's forward and backward passes: the MSE, the sample counts, and the gradient of
/// the loss for every trained variable (a table with a gradient sink gets its part there).
pub struct StepGradients {
    /// The batch's mean squared colour error.
    pub mse: f64,
    /// Samples drawn, tested and evaluated.
    pub samples: SampleCounts,
    /// The loss's gradients.
    pub grads: GradStore,
}

/// Whether the field's fused step can serve a step of `settings` on `field`: samples are
/// skipped (an occupancy grid or early termination), by a sampler that does not refine, with
/// no distortion loss. The field may still have no fused step (then [`fused_gradients`] says
/// so); rays tracked for camera refinement need autograd too.
pub(crate) fn fused_step_applies(
    settings: &StepSettings,
    field: &dyn nerf_render::field::Field,
) -> bool {
    settings.distortion_loss == 0.0
        && !settings.sampler.refines()
        && settings.renderer.skips_samples(field)
}

/// The field's fused step on `rays`: `None` when the model has none
/// ([`nerf_field::trainable::TrainingFastPaths::fused_gradients`]). `field` is the training
/// field (its occupancy grid is marched); the sample depths are drawn from `rng` as the
/// renderer draws them.
pub fn fused_gradients(
    model: &TrainModel,
    settings: &StepSettings,
    field: &dyn nerf_render::field::Field,
    rays: &Rays,
    background: &StepBackground,
    rng: &mut TrainRng,
) -> Result<Option<StepGradients>> {
    // The depths are drawn before asking for the fast path, as the renderer draws them, so a
    // model without one leaves the generator where a model whose kernel declines leaves it.
    let lengths = settings.sampler.compact_lengths(rays, Some(rng))?;
    let target = background.target.flatten_all()?.to_vec1::<f32>()?;
    let behind = match &background.random {
        Some(b) => b.flatten_all()?.to_vec1::<f32>()?,
        None => settings.renderer.background.repeat(rays.len()),
    };
    let batch = FusedBatch {
        rays,
        lengths: &lengths,
        target: &target,
        background: &behind,
        occupancy: field.occupancy(),
        early_termination: settings.renderer.early_termination,
    };
    let Some(fast) = model.field.fast_paths() else {
        return Ok(None);
    };
    Ok(fast.fused_gradients(&batch)?.map(|out| StepGradients {
        mse: out.mse,
        samples: out.samples,
        grads: out.grads,
    }))
}

/// The step through autograd: the batch rendered by `field`, composited onto the background,
/// the MSE (plus the distortion loss when weighted) and its backward pass.
pub(crate) fn graph_gradients(
    field: &dyn nerf_render::field::Field,
    settings: &StepSettings,
    rays: &Rays,
    background: &StepBackground,
    rng: &mut TrainRng,
) -> Result<StepGradients> {
    let mut renderer = settings.renderer;
    renderer.distortion_loss = settings.distortion_loss > 0.0;
    if background.random.is_some() {
        renderer.background = nerf_render::renderer::BLACK;
    }
    let out = renderer.render(field, settings.sampler.as_ref(), rays, Some(rng))?;
    let color = match &background.random {
        Some(b) => out
            .color
            .add(&out.opacity.affine(-1.0, 1.0)?.broadcast_mul(b)?)?,
        None => out.color,
    };
    let mse = color.sub(&background.target)?.sqr()?.mean_all()?;
    let loss = match &out.distortion {
        Some(d) => mse.add(&d.mean_all()?.affine(settings.distortion_loss, 0.0)?)?,
        None => mse.clone(),
    };
    Ok(StepGradients {
        mse: mse.to_scalar::<f32>()? as f64,
        samples: out.samples,
        grads: loss.backward()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::image::RgbImage;
    use nerf_scene::dataset::PixelMask;
    use rand::SeedableRng;

    #[test]
    fn masked_pixels_are_never_drawn_and_used_ones_uniformly() {
        // Three 2×2 images: the first unmasked, the second using pixel 3 only, the third
        // pixels 0 and 1: 4 + 1 + 2 used pixels in all.
        let image = RgbImage::new(2, 2, vec![0.0; 12]).unwrap();
        let flags = |used: [bool; 4]| Some(PixelMask::from_flags(used.to_vec()));
        let dataset = Dataset {
            frames: Vec::new(),
            images: vec![image; 3],
            transparency: Vec::new(),
            width: 2,
            height: 2,
            masks: vec![
                None,
                flags([false, false, false, true]),
                flags([true, true, false, false]),
            ],
            normalisation: None,
            capture: None,
        };
        let mut rng = TrainRng::seed_from_u64(7);
        let n = 70_000;
        let picks = used_pixel_picks(&dataset, n, &mut rng);
        let mut counts = [[0usize; 4]; 3];
        for (image, pixel) in picks {
            counts[image][pixel] += 1;
        }
        assert_eq!(counts[1][..3], [0, 0, 0]);
        assert_eq!(counts[2][2..], [0, 0]);
        // Each of the 7 used pixels gets about n / 7 = 10000 draws.
        let used = [
            counts[0][0],
            counts[0][1],
            counts[0][2],
            counts[0][3],
            counts[1][3],
            counts[2][0],
            counts[2][1],
        ];
        assert!(
            used.iter().all(|&c| (9_400..10_600).contains(&c)),
            "{used:?}"
        );
    }
}
