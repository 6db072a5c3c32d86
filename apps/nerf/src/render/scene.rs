//! Rendering jobs: surround views of a field, and the homework's visualisations.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use candle_core::{Device, Tensor};

use nerf::config::Config;

use super::pointcloud::{PointSplatter, PointView};
use crate::limits;
use nerf::core::camera::PerspectiveCamera;
use nerf::core::sdf::SdfVolume;
use nerf::field::trainable::BoxedField;
use nerf::io::images::{viridis_image, write_gif, write_npy, write_png};
use nerf::io::output::prepare_out_dir;
use nerf::io::progress::progress_bar;
use nerf::kernels::sample_points::sample_points;
use nerf::render::bands::{band_ndc, band_rays, pixel_bands};
use nerf::render::field::Field;
use nerf::render::ray_sampler::RaySampler;
use nerf::render::view::{render_view_interruptible, Interrupt, Pipeline, RenderedView};
use nerf::RgbImage;

/// The sizes of the pieces a job works through (see the working-memory part of
/// [`limits`]): rays per band of an image, sample points per pass of `point_vis`, grid points
/// per evaluation of a mesh grid. Outputs do not depend on them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WorkChunks {
    /// Rays made and rendered at once (rounded to whole renderer chunks where rendered).
    pub rays: usize,
    /// Sample points made and splatted at once for `point_vis`.
    pub points: usize,
    /// Grid points evaluated at once for a mesh.
    pub grid_points: usize,
}

impl Default for WorkChunks {
    fn default() -> Self {
        Self {
            rays: limits::BAND_RAYS,
            points: limits::POINT_SAMPLES,
            grid_points: limits::GRID_BATCH,
        }
    }
}

impl WorkChunks {
    /// The environment variable that lowers every piece (for tests of chunking).
    pub const ENV: &'static str = "NERF_WORK_CHUNK";

    /// The default pieces, each lowered to at most `n` items (at least 1).
    pub fn at_most(n: usize) -> Self {
        let d = Self::default();
        let n = n.max(1);
        Self {
            rays: d.rays.min(n),
            points: d.points.min(n),
            grid_points: d.grid_points.min(n),
        }
    }

    /// The default pieces, or those of [`WorkChunks::at_most`] `N` when `NERF_WORK_CHUNK=N`
    /// is set; an error naming the variable when it is not a whole number of at least 1.
    pub fn from_env() -> Result<Self> {
        match std::env::var(Self::ENV) {
            Err(std::env::VarError::NotPresent) => Ok(Self::default()),
            Ok(v) => match v.trim().parse::<usize>() {
                Ok(n) if n >= 1 => Ok(Self::at_most(n)),
                _ => bail!(
                    "{}: must be a whole number of at least 1 (got `{v}`)",
                    Self::ENV
                ),
            },
            Err(e) => bail!("{}: {e}", Self::ENV),
        }
    }
}

/// Renders every camera with a progress bar, each image in bands of the default size.
pub fn render_views(
    pipeline: &Pipeline,
    cameras: &[PerspectiveCamera],
    size: (usize, usize),
    device: &Device,
) -> Result<Vec<RenderedView>> {
    let band = WorkChunks::default().rays;
    render_views_in_bands(pipeline, cameras, size, band, device)
}

/// [`render_views`] with images rendered about `band` rays at a time (whole renderer chunks,
/// so the images do not depend on it).
pub fn render_views_in_bands(
    pipeline: &Pipeline,
    cameras: &[PerspectiveCamera],
    size: (usize, usize),
    band: usize,
    device: &Device,
) -> Result<Vec<RenderedView>> {
    let band = pipeline.rays_per_band(band);
    let bar = progress_bar(cameras.len() as u64, "rendering");
    let frames = cameras
        .iter()
        .map(|cam| {
            let never = Interrupt {
                band,
                stop: &|| false,
            };
            let f = render_view_interruptible(
                pipeline,
                &nerf::Camera::from(*cam),
                size,
                device,
                never,
            )?
            .context("a render nobody stops was stopped");
            bar.inc(1);
            f
        })
        .collect::<Result<Vec<_>>>();
    bar.finish_and_clear();
    frames
}

/// The homework's `vis_grid`: `((xy + 1) / 2.001, 0)` per pixel, `band` pixels at a time.
pub fn grid_image(width: usize, height: usize, band: usize, device: &Device) -> Result<RgbImage> {
    let mut data = Vec::with_capacity(3 * width * height);
    for pixels in pixel_bands(width * height, band) {
        let n = pixels.len();
        let flat: Vec<f32> = band_ndc(width, height, pixels)
            .into_iter()
            .flat_map(|[x, y]| [x as f32, y as f32])
            .collect();
        let xy = Tensor::from_vec(flat, (n, 2), device)?;
        let rg = ((xy + 1.0)? / 2.001)?;
        let rgb = Tensor::cat(&[&rg, &rg.narrow(1, 0, 1)?.zeros_like()?], 1)?;
        data.extend(rgb.flatten_all()?.to_vec1::<f32>()?);
    }
    RgbImage::new(width, height, data)
}

/// The homework's `vis_rays`: `|direction|` per pixel, `band` pixels at a time.
pub fn ray_image(
    camera: &nerf::Camera,
    (width, height): (usize, usize),
    band: usize,
    device: &Device,
) -> Result<RgbImage> {
    let mut data = Vec::with_capacity(3 * width * height);
    for pixels in pixel_bands(width * height, band) {
        let rays = band_rays(camera, (width, height), pixels, device)?;
        data.extend(rays.directions.abs()?.flatten_all()?.to_vec1::<f32>()?);
    }
    RgbImage::new(width, height, data)
}

/// Camera 0's sample points splatted as a `size²` point cloud image (the homework's
/// `point_vis`), made and splatted about `max_points` points at a time (whole rays, at least
/// one).
pub fn point_image(
    camera: &nerf::Camera,
    (width, height): (usize, usize),
    sampler: &dyn RaySampler,
    size: usize,
    max_points: usize,
    device: &Device,
) -> Result<RgbImage> {
    let mut splatter = PointSplatter::new(size, &PointView::default())?;
    // The points every sampler starts from.
    let band = (max_points / sampler.drawn_per_ray()).max(1);
    for pixels in pixel_bands(width * height, band) {
        let rays = band_rays(camera, (width, height), pixels, device)?;
        let lengths = sampler.lengths(&rays, None)?;
        let points = sample_points(&rays.origins, &rays.directions, &lengths)?;
        splatter.add(&points.flatten_all()?.to_vec1::<f32>()?);
    }
    splatter.finish()
}

/// Writes a job's files all or none: `write` pushes each file it writes; when it fails, the
/// files it wrote are removed (each write is atomic, so the failed one left nothing).
pub(crate) fn write_all(
    write: impl FnOnce(&mut Vec<PathBuf>) -> Result<()>,
) -> Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    match write(&mut written) {
        Ok(()) => Ok(written),
        Err(e) => {
            for p in &written {
                let _ = std::fs::remove_file(p);
            }
            Err(e)
        }
    }
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

/// Writes the frames' colours as the animated GIF `out_dir/gif_name` (10 fps) and, with
/// `raw`, every frame's colour and depth as `.npy` ([`write_raw_frames`]), pushing each file
/// written onto `written`.
fn write_frames(
    out_dir: &Path,
    gif_name: &str,
    (colors, depths): (&[RgbImage], &[Vec<f32>]),
    raw: bool,
    written: &mut Vec<PathBuf>,
) -> Result<()> {
    let gif = out_dir.join(gif_name);
    write_gif(&gif, colors, 10)?;
    written.push(gif);
    if raw {
        write_raw_frames(out_dir, colors, depths, written)?;
    }
    Ok(())
}

/// Writes `color_{i:03}.npy` `(H, W, 3)` and `depth_{i:03}.npy` `(H, W)` for every frame
/// (`colors[i]`, `depths[i]`), pushing each file written onto `written`.
pub fn write_raw_frames(
    out_dir: &Path,
    colors: &[RgbImage],
    depths: &[Vec<f32>],
    written: &mut Vec<PathBuf>,
) -> Result<()> {
    remove_stale_raw_frames(out_dir, colors.len())?;
    for (i, (c, d)) in colors.iter().zip(depths).enumerate() {
        let (w, h) = (c.width as u64, c.height as u64);
        let color = out_dir.join(format!("color_{i:03}.npy"));
        write_npy(&color, &[h, w, 3], &c.data)?;
        written.push(color);
        let depth = out_dir.join(format!("depth_{i:03}.npy"));
        write_npy(&depth, &[h, w], d)?;
        written.push(depth);
    }
    Ok(())
}

/// The index of the view whose depth is shown: view 2, as the homework, or the last view when
/// there are fewer.
pub fn depth_view_index(n_views: usize) -> usize {
    2.min(n_views.saturating_sub(1))
}

/// The frames' colours (for the GIF) and depths, taken apart without copies.
fn split_frames(frames: Vec<RenderedView>) -> (Vec<RgbImage>, Vec<Vec<f32>>) {
    frames.into_iter().map(|f| (f.color, f.depth)).unzip()
}

/// `nerf render` for an SDF scene: grid_vis, ray_vis, point_vis (camera 0), render_cube.gif
/// (all surround views), depth.png (view 2) and, with `raw`, the float arrays. Everything is
/// rendered before the first file is written, so a job that fails leaves no outputs.
pub fn render_sdf_scene(
    config: &Config,
    out_dir: &Path,
    raw: bool,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let chunks = WorkChunks::from_env()?;
    let field = config.sdf_field(device)?;
    let sampler = config.sampler()?;
    let renderer = config.renderer()?;
    let (w, h) = config.image_size();
    let cameras = config.surround_cameras();
    prepare_out_dir(out_dir)?;
    let grid = grid_image(w, h, chunks.rays, device)?;
    let first: nerf::Camera = cameras[0].into();
    let rays = ray_image(&first, (w, h), chunks.rays, device)?;
    let points = point_image(&first, (w, h), sampler.as_ref(), 256, chunks.points, device)?;
    let frames = render_views_in_bands(
        &Pipeline::new(&field, &*sampler, &renderer),
        &cameras,
        (w, h),
        chunks.rays,
        device,
    )?;
    let (colors, depths) = split_frames(frames);
    let depth = viridis_image(w, h, &depths[depth_view_index(depths.len())])?;
    write_all(|written| {
        for (name, img) in [
            ("grid_vis.png", &grid),
            ("ray_vis.png", &rays),
            ("point_vis.png", &points),
            ("depth.png", &depth),
        ] {
            let p = out_dir.join(name);
            write_png(&p, img)?;
            written.push(p);
        }
        write_frames(out_dir, "render_cube.gif", (&colors, &depths), raw, written)
    })
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
    let render = config.render_settings()?;
    let frames = render_views(
        &render.with(field),
        &config.surround_cameras(),
        config.image_size(),
        device,
    )?;
    let (colors, _) = split_frames(frames);
    write_gif(path, &colors, 10)?;
    Ok(path.to_path_buf())
}

/// `nerf render` for a NeRF config: loads `checkpoint` and writes render_nerf.gif (and, with
/// `raw`, the float arrays) into `out_dir`, all rendered before the first is written.
pub fn render_nerf_scene(
    config: &Config,
    checkpoint: &Path,
    out_dir: &Path,
    raw: bool,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let chunks = WorkChunks::from_env()?;
    let field = config.load_field(checkpoint, device)?;
    let views = crate::render::scene_frame::render_cameras(config, checkpoint)?;
    prepare_out_dir(out_dir)?;
    let render = config.render_settings()?;
    let frames = render_views_in_bands(
        &render.with(&*field),
        &views.cameras,
        config.image_size(),
        chunks.rays,
        device,
    )?;
    let (colors, depths) = split_frames(frames);
    write_all(|written| write_frames(out_dir, "render_nerf.gif", (&colors, &depths), raw, written))
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
    if !config.implicit_function.is_sdf_volume() {
        return render_nerf_scene(config, &config.checkpoint(checkpoint), out_dir, raw, device);
    }
    if let Some(c) = checkpoint {
        anyhow::bail!(
            "--checkpoint {}: an SDF scene has no checkpoint (NeRF configs only)",
            c.display()
        );
    }
    render_sdf_scene(config, out_dir, raw, device)
}

/// The field a config describes, loaded and ready to render.
pub enum SceneField {
    /// An SDF volume, with the values it was made from.
    Sdf {
        /// The field.
        field: BoxedField,
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
            SceneField::Sdf { field, .. } => field.as_ref(),
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
    if !config.implicit_function.is_sdf_volume() {
        let path = config.checkpoint(checkpoint);
        return Ok(SceneField::Nerf(config.load_field(&path, device)?));
    }
    match checkpoint {
        Some(c) => anyhow::bail!(
            "--checkpoint {}: an SDF scene has no checkpoint (NeRF configs only)",
            c.display()
        ),
        None => Ok(SceneField::Sdf {
            field: Box::new(config.sdf_field(device)?),
            volume: config.sdf_volume()?,
        }),
    }
}
