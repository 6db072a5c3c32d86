//! Rendering jobs: surround views of a field, and the homework's visualisations.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use candle_core::{Device, Tensor};

use crate::app::config::{Config, ImplicitFunctionConfig};
use crate::core::camera::PerspectiveCamera;
use crate::core::rays::{pixel_grid, Rays};
use crate::core::sdf::SdfVolume;
use crate::field::sdf::SdfField;
use crate::io::images::{
    prepare_out_dir, viridis_image, write_gif, write_npy, write_png, RgbImage,
};
use crate::io::progress::progress_bar;
use crate::render::field::Field;
use crate::render::pointcloud::{render_points, PointView};
use crate::render::renderer::VolumeRenderer;
use crate::render::sampler::StratifiedSampler;
use crate::render::view::{render_view, RenderedView};

/// Renders every camera with a progress bar.
pub fn render_views(
    field: &dyn Field,
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

/// Removes `color_{i:03}.npy` and `depth_{i:03}.npy` files with `i ≥ n_frames` that an
/// earlier run with more poses left in `out_dir`, so that the directory holds one clean set.
/// Only files of exactly that naming are touched.
fn remove_stale_raw_frames(out_dir: &Path, n_frames: usize) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(out_dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        let index = name
            .strip_suffix(".npy")
            .and_then(|s| {
                s.strip_prefix("color_")
                    .or_else(|| s.strip_prefix("depth_"))
            })
            .filter(|digits| digits.len() >= 3 && digits.bytes().all(|b| b.is_ascii_digit()))
            .and_then(|digits| digits.parse::<usize>().ok());
        if index.is_some_and(|i| i >= n_frames) {
            std::fs::remove_file(entry.path())
                .with_context(|| format!("cannot remove stale frame {}", entry.path().display()))?;
        }
    }
    Ok(())
}

/// Writes `color_{i:03}.npy` `(H, W, 3)` and `depth_{i:03}.npy` `(H, W)` for every frame.
pub fn write_raw_frames(out_dir: &Path, frames: &[RenderedView]) -> Result<Vec<PathBuf>> {
    remove_stale_raw_frames(out_dir, frames.len())?;
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
    let field = config.sdf_field(device)?;
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
    field: &dyn Field,
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
    let field = config.load_field(checkpoint, device)?;
    prepare_out_dir(out_dir)?;
    let frames = render_views(
        &*field,
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

/// `nerf render`: the SDF scene's outputs, or the NeRF's GIF from the checkpoint that
/// [`Config::checkpoint`] picks for `checkpoint`, by the config's field.
pub fn render_scene(
    config: &Config,
    checkpoint: Option<&Path>,
    out_dir: &Path,
    raw: bool,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    match &config.implicit_function {
        ImplicitFunctionConfig::SdfVolume(_) => {
            if let Some(c) = checkpoint {
                anyhow::bail!(
                    "--checkpoint {}: an SDF scene has no checkpoint (NeRF configs only)",
                    c.display()
                );
            }
            render_sdf_scene(config, out_dir, raw, device)
        }
        ImplicitFunctionConfig::Nerf(_) | ImplicitFunctionConfig::Ngp(_) => {
            render_nerf_scene(config, &config.checkpoint(checkpoint), out_dir, raw, device)
        }
    }
}

/// The field a config describes, loaded and ready to render.
pub enum SceneField {
    /// An SDF volume, with the values it was made from.
    Sdf {
        /// The field.
        field: SdfField,
        /// Its shape, density and colour parameters.
        volume: SdfVolume,
    },
    /// A trained field, the NeRF MLP or the hash grid (with its occupancy grid when the
    /// config asks for one).
    Nerf(Box<dyn Field + Send + Sync>),
}

impl SceneField {
    /// The field as the renderer sees it.
    pub fn as_field(&self) -> &dyn Field {
        match self {
            SceneField::Sdf { field, .. } => field,
            SceneField::Nerf(field) => field.as_ref(),
        }
    }
}

/// Loads the config's field: the SDF volume, or the NeRF from the checkpoint that
/// [`Config::checkpoint`] picks for `checkpoint`. A checkpoint given for an SDF scene is an
/// error.
pub fn load_scene_field(
    config: &Config,
    checkpoint: Option<&Path>,
    device: &Device,
) -> Result<SceneField> {
    match &config.implicit_function {
        ImplicitFunctionConfig::SdfVolume(_) => {
            if let Some(c) = checkpoint {
                anyhow::bail!(
                    "--checkpoint {}: an SDF scene has no checkpoint (NeRF configs only)",
                    c.display()
                );
            }
            Ok(SceneField::Sdf {
                field: config.sdf_field(device)?,
                volume: config.sdf_volume()?,
            })
        }
        ImplicitFunctionConfig::Nerf(_) | ImplicitFunctionConfig::Ngp(_) => Ok(SceneField::Nerf(
            config.load_field(&config.checkpoint(checkpoint), device)?,
        )),
    }
}
