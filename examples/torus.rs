//! A new kind of field defined outside the crate: a torus SDF volume.
//!
//! Shows how to implement the [`nerf::Field`] trait with Candle tensor ops: the torus's signed
//! distance at the sample points, turned into density and σ exactly as the homework's SDF volume
//! does (reusing the crate's `sdf_to_density` and `density_to_sigma`), with a rainbow colour.
//! The renderer, sampler and [`nerf::render_view`] then work on it unchanged. The cameras circle
//! above the ring, looking down at it, so the hole is visible.
//!
//! Run: `cargo run --release --example torus -- OUTDIR` (default `images`); writes `torus.gif`
//! (20 views) and `torus.png` (the first view).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use candle_core::{Device, Tensor, D};
use glam::DVec3;
use nerf::{density_to_sigma, sdf_to_density};
use nerf::{
    look_at_view_transform, render_view, Field, FieldOutput, PerspectiveCamera, Pipeline,
    RaySamples, StratifiedSampler, VolumeRenderer,
};

/// A torus centred at the origin, its ring in the xz plane (around the y axis).
struct TorusField {
    /// Distance from the centre to the middle of the tube.
    major_radius: f32,
    /// Radius of the tube.
    minor_radius: f32,
    /// `(1,)` the homework's α and β of the SDF → density conversion.
    alpha: Tensor,
    beta: Tensor,
}

impl TorusField {
    fn new(major_radius: f32, minor_radius: f32, device: &Device) -> Result<Self> {
        Ok(Self {
            major_radius,
            minor_radius,
            alpha: Tensor::new(&[1f32], device)?,
            beta: Tensor::new(&[0.05f32], device)?,
        })
    }

    /// Signed distance of points `(N, S, 3)`: `‖(‖p_xz‖ − R, p_y)‖ − r`, returned `(N, S, 1)`.
    fn signed_distance(&self, points: &Tensor) -> Result<Tensor> {
        let x = points.narrow(D::Minus1, 0, 1)?;
        let y = points.narrow(D::Minus1, 1, 1)?;
        let z = points.narrow(D::Minus1, 2, 1)?;
        let ring = x
            .sqr()?
            .add(&z.sqr()?)?
            .sqrt()?
            .affine(1.0, -self.major_radius as f64)?;
        let tube = ring.sqr()?.add(&y.sqr()?)?.sqrt()?;
        Ok(tube.affine(1.0, -self.minor_radius as f64)?)
    }
}

impl Field for TorusField {
    fn evaluate(
        &self,
        samples: &RaySamples,
        deltas: &Tensor,
        _directions: &Tensor,
    ) -> Result<FieldOutput> {
        let sdf = self.signed_distance(&samples.points)?;
        let density = sdf_to_density(&sdf, &self.alpha, &self.beta)?;
        let density = density_to_sigma(&density, deltas)?;
        // The homework's rainbow: clamp(|p − centre|, 0.02, 0.98).
        let feature = samples.points.abs()?.clamp(0.02f32, 0.98f32)?;
        Ok(FieldOutput { density, feature })
    }
}

fn main() -> Result<()> {
    nerf::tune_allocator();
    let out_dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "images".into()));
    std::fs::create_dir_all(&out_dir)?;

    let device = Device::Cpu;
    let field = TorusField::new(1.0, 0.35, &device)?;
    let sampler = StratifiedSampler::new(64, 0.0, 5.0)?;
    let renderer = VolumeRenderer::new(32768, false)?;
    let size = 128;

    // 20 eyes on a circle 3 units from the origin, 35° above the ring's plane.
    let (distance, elevation) = (3.0f64, 35f64.to_radians());
    let cameras: Vec<PerspectiveCamera> = (0..20)
        .map(|i| {
            let azimuth = i as f64 * std::f64::consts::TAU / 20.0;
            let eye = distance
                * DVec3::new(
                    elevation.cos() * azimuth.sin(),
                    elevation.sin(),
                    elevation.cos() * azimuth.cos(),
                );
            let (r, t) = look_at_view_transform(eye, DVec3::ZERO, DVec3::Y);
            PerspectiveCamera::new(r, t, 1.0)
        })
        .collect();

    let start = Instant::now();
    let pipeline = Pipeline::new(&field, &sampler, &renderer);
    let mut frames = Vec::with_capacity(cameras.len());
    for camera in &cameras {
        frames.push(
            render_view(
                &pipeline,
                &nerf::Camera::from(*camera),
                (size, size),
                &device,
            )?
            .color,
        );
    }
    let rendered = start.elapsed().as_secs_f64();

    let gif = out_dir.join("torus.gif");
    let png = out_dir.join("torus.png");
    nerf::io::images::write_gif(&gif, &frames, 10)?;
    nerf::io::images::write_png(&png, &frames[0])?;
    println!(
        "wrote {} ({} frames of {size}x{size}, rendered in {rendered:.2} s) and {}",
        gif.display(),
        frames.len(),
        png.display()
    );
    Ok(())
}
