//! A new trainable field kind, defined outside the crate, trained on lego with the library's
//! own trainer ([`nerf::fit`]): checkpoints, resume, logging and the optimiser come from the
//! crate; the field ([`voxels`]) is this example's.
//!
//! The run takes its training settings from the `nerf_lego_fast` config at 32×32 and swaps the
//! model for a 24³ voxel grid, trains one epoch (100 steps of 256 rays), then renders a test
//! view with the trained grid.
//!
//! Run: `cargo run --release --example custom_field -- [OUTDIR] [LEGO_DIR]` (defaults `images`
//! and `../shared/data/lego`); writes `OUTDIR/voxels.safetensors`, its log and `voxels.png`.

mod voxels;

use anyhow::{Context, Result};
use candle_core::Device;
use nerf::config::Config;
use nerf::io::dataset::{Dataset, Split};
use nerf::{fit, render_view, Hooks, RunLimits, TrainModel, TrainPaths};
use std::path::PathBuf;

fn main() -> Result<()> {
    // The library's progress notes (fresh run, resume, step lines) on stderr.
    nerf::core::term::print_library_messages();
    let mut args = std::env::args().skip(1);
    let out = PathBuf::from(args.next().unwrap_or_else(|| "images".into()));
    let lego = PathBuf::from(args.next().unwrap_or_else(|| "../shared/data/lego".into()));
    std::fs::create_dir_all(&out)?;
    let device = Device::Cpu;

    let config = Config::load(
        "nerf_lego_fast",
        &[
            "data.image_size=[32,32]".into(),
            "training.batch_size=256".into(),
        ],
    )?;
    let spec = voxels::VoxelSpec {
        resolution: 24,
        half_extent: 1.5,
    };
    let settings = voxels::train_settings(&config, spec)?;
    let (w, h) = config.image_size();
    let white = config.renderer.white_background;
    let dataset = Dataset::load(&lego, Split::Train, w, h, white)
        .with_context(|| format!("lego training images at {}", lego.display()))?;
    let paths = TrainPaths {
        checkpoint: out.join("voxels.safetensors"),
        log: out.join("voxels_log.jsonl"),
        images: out.clone(),
    };
    // A fresh run each time.
    let _ = std::fs::remove_file(&paths.checkpoint);
    let _ = std::fs::remove_file(&paths.log);
    let limits = RunLimits::default();
    let outcome = fit(
        &settings,
        &dataset,
        &paths,
        limits,
        None,
        Hooks::default(),
        &device,
    )?;
    let losses: Vec<f64> = std::fs::read_to_string(&paths.log)?
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()?["loss"].as_f64())
        .collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let tenth = (losses.len() / 10).max(1);
    println!(
        "trained a {}³ voxel grid for {} steps: loss {:.4} (first tenth) -> {:.4} (last tenth)",
        spec.resolution,
        outcome.info().adam_step,
        mean(&losses[..tenth]),
        mean(&losses[losses.len() - tenth..])
    );

    // The checkpoint loads back into the example's field kind, and renders.
    let model = TrainModel::from_checkpoint(&spec, &paths.checkpoint, &device)?.model;
    let test = Dataset::load_first(&lego, Split::Test, w, h, white, Some(1))?;
    let field = model.render_field();
    let render = config.render_settings()?;
    let view = render_view(
        &render.with(&*field),
        &test.frames[0].camera,
        (w, h),
        &device,
    )?;
    let png = out.join("voxels.png");
    nerf::io::images::write_png(&png, &view.color)?;
    println!(
        "test view 0: PSNR {:.2} dB against the image; wrote {}",
        nerf::core::metrics::psnr(&view.color, &test.images[0]),
        png.display()
    );
    Ok(())
}
