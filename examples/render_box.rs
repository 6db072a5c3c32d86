//! Renders the homework's rainbow box from 20 cameras around it and writes a turntable GIF.
//!
//! Shows the plain rendering path: an [`nerf::SdfField`] with fixed parameters, the stratified
//! sampler, the volume renderer and [`nerf::render_view`], one camera at a time.
//!
//! Run: `cargo run --release --example render_box -- OUTDIR [SIZE]` (defaults `images`, 128).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use candle_core::Device;
use nerf::{render_view, Pipeline, SdfField, SdfVolume, StratifiedSampler, VolumeRenderer};

fn main() -> Result<()> {
    nerf::tune_allocator();
    let mut args = std::env::args().skip(1);
    let out_dir = PathBuf::from(args.next().unwrap_or_else(|| "images".into()));
    let size: usize = match args.next() {
        Some(s) => s.parse().with_context(|| format!("bad image size {s:?}"))?,
        None => 128,
    };
    std::fs::create_dir_all(&out_dir)?;

    let device = Device::Cpu;
    // The homework's box: side 1.75 at the origin, alpha 1, beta 0.05, rainbow colours.
    let volume = SdfVolume::homework_box();
    let field = SdfField::fixed(&volume, &device)?;
    let sampler = StratifiedSampler::new(64, 0.0, 5.0)?;
    let renderer = VolumeRenderer::new(32768, false)?;
    let pipeline = Pipeline::new(&field, &sampler, &renderer);

    let start = Instant::now();
    let frames = nerf::surround_cameras(3.0, 20, glam::DVec3::Y, 1.0)
        .iter()
        .map(|camera| {
            Ok(render_view(
                &pipeline,
                &nerf::Camera::from(*camera),
                (size, size),
                &device,
            )?
            .color)
        })
        .collect::<Result<Vec<_>>>()?;
    let path = out_dir.join("box.gif");
    nerf::io::images::write_gif(&path, &frames, 10)?;
    println!(
        "wrote {} ({} frames of {size}x{size}, rendered in {:.2} s)",
        path.display(),
        frames.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
