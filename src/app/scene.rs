//! Rendering jobs: surround views of a field, and the homework's visualisations.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use candle_core::{Device, Tensor};
use indicatif::{ProgressBar, ProgressStyle};

use crate::app::config::Config;
use crate::core::camera::PerspectiveCamera;
use crate::core::rays::{pixel_grid, Rays};
use crate::io::images::{viridis_image, write_gif, write_npy, write_png, RgbImage};
use crate::render::field::Field;
use crate::render::pointcloud::{render_points, PointView};
use crate::render::renderer::VolumeRenderer;
use crate::render::sampler::StratifiedSampler;

/// One rendered view.
#[derive(Debug, Clone)]
pub struct RenderedView {
    /// `(H·W·3)` colour, row-major.
    pub color: RgbImage,
    /// `(H·W)` depth, row-major.
    pub depth: Vec<f32>,
    /// Samples drawn and evaluated for it.
    pub samples: crate::render::skipping::SampleCounts,
}

/// Renders one camera's full image (no jitter, no gradients needed).
pub fn render_view(
    field: &Field,
    camera: &PerspectiveCamera,
    (width, height): (usize, usize),
    sampler: &StratifiedSampler,
    renderer: &VolumeRenderer,
    device: &Device,
) -> Result<RenderedView> {
    camera.validate()?;
    let rays = Rays::for_image(camera, width, height, device)?;
    let out = renderer.render(field, sampler, &rays, None)?;
    let color = out.color.flatten_all()?.to_vec1::<f32>()?;
    let depth = out.depth.flatten_all()?.to_vec1::<f32>()?;
    Ok(RenderedView {
        color: RgbImage::new(width, height, color)?,
        depth,
        samples: out.samples,
    })
}

/// A progress bar on stderr (drawn only on a terminal).
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// Prints `message` as a line above `bar`, or on stderr when the bar is hidden (stderr is not
/// a terminal, as when training runs in the background with its output in a file): indicatif
/// drops the lines of a hidden bar.
pub fn print_above(bar: &ProgressBar, message: &str) {
    if bar.is_hidden() {
        eprintln!("{message}");
    } else {
        bar.println(message);
    }
}

/// Renders every camera with a progress bar.
pub fn render_views(
    field: &Field,
    cameras: &[PerspectiveCamera],
    size: (usize, usize),
    sampler: &StratifiedSampler,
    renderer: &VolumeRenderer,
    device: &Device,
) -> Result<Vec<RenderedView>> {
    let bar = progress_bar(cameras.len() as u64, "rendering");
    let frames = cameras
        .iter()
        .map(|cam| {
            let f = render_view(field, cam, size, sampler, renderer, device);
            bar.inc(1);
            f
        })
        .collect::<Result<Vec<_>>>();
    bar.finish_and_clear();
    frames
}

/// The homework's `vis_grid`: `((xy + 1) / 2.001, 0)` per pixel.
pub fn grid_image(width: usize, height: usize, device: &Device) -> Result<RgbImage> {
    let xy = pixel_grid(width, height, device)?;
    let rg = ((xy + 1.0)? / 2.001)?;
    let rgb = Tensor::cat(&[&rg, &rg.narrow(1, 0, 1)?.zeros_like()?], 1)?;
    RgbImage::new(width, height, rgb.flatten_all()?.to_vec1::<f32>()?)
}

/// The homework's `vis_rays`: `|direction|` per pixel.
pub fn ray_image(
    camera: &PerspectiveCamera,
    width: usize,
    height: usize,
    device: &Device,
) -> Result<RgbImage> {
    let rays = Rays::for_image(camera, width, height, device)?;
    RgbImage::new(
        width,
        height,
        rays.directions.abs()?.flatten_all()?.to_vec1::<f32>()?,
    )
}

/// Camera 0's sample points splatted as a point cloud (the homework's `point_vis`).
pub fn point_image(
    camera: &PerspectiveCamera,
    (width, height): (usize, usize),
    sampler: &StratifiedSampler,
    size: usize,
    device: &Device,
) -> Result<RgbImage> {
    let rays = Rays::for_image(camera, width, height, device)?;
    let points = sampler
        .sample(&rays, None)?
        .points
        .flatten_all()?
        .to_vec1::<f32>()?;
    render_points(&points, size, &PointView::default())
}

/// Creates `dir` (and parents), with an error that names it.
pub fn prepare_out_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create output directory {}", dir.display()))?;
    let probe = dir.join(format!(".nerf-write-test.{}", std::process::id()));
    std::fs::write(&probe, b"")
        .with_context(|| format!("output directory {} is not writable", dir.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// Writes `color_{i:03}.npy` `(H, W, 3)` and `depth_{i:03}.npy` `(H, W)` for every frame.
pub fn write_raw_frames(out_dir: &Path, frames: &[RenderedView]) -> Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        let (w, h) = (f.color.width as u64, f.color.height as u64);
        let c = out_dir.join(format!("color_{i:03}.npy"));
        write_npy(&c, &[h, w, 3], &f.color.data)?;
        let d = out_dir.join(format!("depth_{i:03}.npy"));
        write_npy(&d, &[h, w], &f.depth)?;
        written.extend([c, d]);
    }
    Ok(written)
}

/// The index of the view whose depth is shown: view 2, as the homework, or the last view when
/// there are fewer.
pub fn depth_view_index(n_views: usize) -> usize {
    2.min(n_views.saturating_sub(1))
}

/// `nerf render` for an SDF scene: grid_vis, ray_vis, point_vis (camera 0), render_cube.gif
/// (all surround views), depth.png (view 2) and, with `raw`, the float arrays.
pub fn render_sdf_scene(
    config: &Config,
    out_dir: &Path,
    raw: bool,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let field = config.sdf_field()?;
    let sampler = config.sampler()?;
    let renderer = config.renderer()?;
    let (w, h) = config.image_size();
    let cameras = config.surround_cameras();
    prepare_out_dir(out_dir)?;
    let mut written = Vec::new();
    let mut save_png = |name: &str, img: &RgbImage| -> Result<()> {
        let p = out_dir.join(name);
        write_png(&p, img)?;
        written.push(p);
        Ok(())
    };
    save_png("grid_vis.png", &grid_image(w, h, device)?)?;
    save_png("ray_vis.png", &ray_image(&cameras[0], w, h, device)?)?;
    save_png(
        "point_vis.png",
        &point_image(&cameras[0], (w, h), &sampler, 256, device)?,
    )?;
    let frames = render_views(&field, &cameras, (w, h), &sampler, &renderer, device)?;
    let d = &frames[depth_view_index(frames.len())];
    save_png("depth.png", &viridis_image(w, h, &d.depth)?)?;
    let gif = out_dir.join("render_cube.gif");
    write_gif(
        &gif,
        &frames.iter().map(|f| f.color.clone()).collect::<Vec<_>>(),
        10,
    )?;
    written.push(gif);
    if raw {
        written.extend(write_raw_frames(out_dir, &frames)?);
    }
    Ok(written)
}

/// Renders the config's surround views of a NeRF field into an animated GIF at `path`.
pub fn render_nerf_gif(
    config: &Config,
    field: &Field,
    path: &Path,
    device: &Device,
) -> Result<PathBuf> {
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        prepare_out_dir(dir)?;
    }
    let frames = render_views(
        field,
        &config.surround_cameras(),
        config.image_size(),
        &config.sampler()?,
        &config.renderer()?,
        device,
    )?;
    write_gif(
        path,
        &frames.iter().map(|f| f.color.clone()).collect::<Vec<_>>(),
        10,
    )?;
    Ok(path.to_path_buf())
}

/// `nerf render` for a NeRF config: loads `checkpoint` and writes render_nerf.gif (and, with
/// `raw`, the float arrays) into `out_dir`.
pub fn render_nerf_scene(
    config: &Config,
    checkpoint: &Path,
    out_dir: &Path,
    raw: bool,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    crate::train::fit::nerf_config(config)?;
    crate::io::checkpoint::ensure_checkpoint_file(checkpoint)?;
    let (state, _) = crate::train::fit::NerfState::load(config, checkpoint, device)?;
    prepare_out_dir(out_dir)?;
    let field = state.field();
    let frames = render_views(
        &field,
        &config.surround_cameras(),
        config.image_size(),
        &config.sampler()?,
        &config.renderer()?,
        device,
    )?;
    let gif = out_dir.join("render_nerf.gif");
    write_gif(
        &gif,
        &frames.iter().map(|f| f.color.clone()).collect::<Vec<_>>(),
        10,
    )?;
    let mut written = vec![gif];
    if raw {
        written.extend(write_raw_frames(out_dir, &frames)?);
    }
    Ok(written)
}
