//! A few training steps of a tiny NeRF on synthetic data: no dataset needed.
//!
//! Shows the training path piece by piece: target images rendered from the homework's rainbow
//! box ([`nerf::SdfField`]) at 32×32 from 4 cameras, a small seeded [`nerf::NerfState`], Adam
//! over its variables, and per step a random batch of rays through the target pixels, rendered
//! with jittered samples through [`nerf::VolumeRenderer::render`], an MSE loss and its backward
//! pass. The loss is printed every 10 steps; at the end the trained model renders camera 0 next
//! to its target.
//!
//! Run: `cargo run --release --example tiny_nerf -- OUTDIR` (default `images`); writes
//! `tiny_nerf.png` (target left, NeRF right).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use candle_core::{Device, Tensor};
use rand::SeedableRng;

use nerf::core::rays::random_pixel_indices;
use nerf::{
    named_vars, render_view, Adam, NerfParams, NerfState, Pipeline, Rays, RgbImage, SdfField,
    SdfVolume, StratifiedSampler, VolumeRenderer,
};

const SIZE: usize = 32;
const STEPS: usize = 100;
const RAYS_PER_CAMERA: usize = 128;

fn main() -> Result<()> {
    nerf::tune_allocator();
    let out_dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "images".into()));
    std::fs::create_dir_all(&out_dir)?;
    let device = Device::Cpu;
    let start = Instant::now();

    // Targets: the rainbow box from 4 cameras around it.
    let target_field = SdfField::fixed(&SdfVolume::homework_box(), &device)?;
    let sampler = StratifiedSampler::new(32, 0.0, 5.0)?;
    let renderer = VolumeRenderer::new(32768, false)?;
    let targets_pipeline = Pipeline::new(&target_field, &sampler, &renderer);
    let cameras: Vec<nerf::Camera> = nerf::surround_cameras(3.0, 4, glam::DVec3::Y, 1.0)
        .into_iter()
        .map(Into::into)
        .collect();
    let targets = cameras
        .iter()
        .map(|c| Ok(render_view(&targets_pipeline, c, (SIZE, SIZE), &device)?.color))
        .collect::<Result<Vec<RgbImage>>>()?;

    // A small NeRF and Adam over its variables.
    let params = NerfParams {
        n_harmonic_functions_xyz: 4,
        n_hidden_neurons_xyz: 64,
        n_hidden_neurons_dir: 32,
        n_layers_xyz: 3,
        append_xyz: vec![],
        ..NerfParams::default()
    };
    let state = NerfState::seeded(&params, 0, &device)?;
    // Much above 2e-3 the density ReLU tends to die early on (σ = 0 everywhere, a black
    // image, loss stuck near 0.053).
    let mut adam = Adam::new(named_vars(&state.varmap), 2e-3)?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);

    for step in 1..=STEPS {
        // A batch of random pixels from every camera: rays and their target colours.
        let mut origins = Vec::new();
        let mut directions = Vec::new();
        let mut target = Vec::new();
        for (camera, image) in cameras.iter().zip(&targets) {
            let pixels = random_pixel_indices(SIZE, SIZE, RAYS_PER_CAMERA, &mut rng);
            let rays = Rays::for_pixels(camera, SIZE, SIZE, &pixels, &device)?;
            origins.push(rays.origins);
            directions.push(rays.directions);
            target.extend(
                pixels
                    .iter()
                    .flat_map(|&p| image.data[3 * p..3 * p + 3].iter().copied()),
            );
        }
        let rays = Rays {
            origins: Tensor::cat(&origins, 0)?,
            directions: Tensor::cat(&directions, 0)?,
            camera_index: None,
        };
        let target = Tensor::from_vec(target, (rays.len(), 3), &device)?;

        // The model with its variables (not detached), so the loss reaches them.
        let field = state.training_field(0.0);
        let out = renderer.render(&field, &sampler, &rays, Some(&mut rng))?;
        let loss = out.color.sub(&target)?.sqr()?.mean_all()?;
        adam.step(&loss.backward()?)?;
        if step == 1 || step % 10 == 0 {
            let mse = loss.to_scalar::<f32>()?;
            println!(
                "step {step:3}  loss {mse:.5}  psnr {:5.2} dB  ({:.1} s)",
                -10.0 * mse.log10(),
                start.elapsed().as_secs_f64()
            );
        }
    }

    // The trained model from camera 0, beside its target.
    let trained = state.field();
    let view = render_view(
        &Pipeline::new(&trained, &sampler, &renderer),
        &cameras[0],
        (SIZE, SIZE),
        &device,
    )?;
    let mut both = vec![0f32; 2 * SIZE * SIZE * 3];
    for y in 0..SIZE {
        let row = 3 * SIZE;
        both[2 * y * row..(2 * y + 1) * row]
            .copy_from_slice(&targets[0].data[y * row..(y + 1) * row]);
        both[(2 * y + 1) * row..(2 * y + 2) * row]
            .copy_from_slice(&view.color.data[y * row..(y + 1) * row]);
    }
    let path = out_dir.join("tiny_nerf.png");
    nerf::io::images::write_png(&path, &RgbImage::new(2 * SIZE, SIZE, both)?)?;
    println!(
        "wrote {} ({:.1} s in all)",
        path.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
