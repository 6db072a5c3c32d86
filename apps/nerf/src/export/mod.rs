//! `nerf export`: what a scene holds, taken out as files other programs read — a coloured
//! mesh (marching cubes on the density), a point cloud (expected depths of the dataset's
//! views) and depth maps.

mod depth_points;
pub mod model_file;
mod surface;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use candle_core::{Device, Tensor};

use crate::render::scene::{load_scene_field, write_all, SceneField, WorkChunks};
use crate::render::scene_frame::{note_scene_frame, stored_transform};
use nerf::config::{Config, OccupancyGridConfig, SizeUse};

use crate::limits;
use depth_points::{depth_points, ColoredPoints};
use nerf::core::camera::Camera;
use nerf::core::marching_cubes::{marching_cubes, TriMesh, VolumeGrid};
use nerf::core::sdf::{Sdf, SdfVolume};
use nerf::io::dataset::{read_split_with, Split};
use nerf::io::images::{viridis_image, write_npy, write_png};
use nerf::io::output::prepare_out_dir;
use nerf::io::ply::{write_mesh_ply, write_points_ply};
use nerf::io::progress::progress_bar;
use nerf::kernels::sdf_volume::sdf_at_density;
use nerf::render::field::Field;
use nerf::render::view::render_view;
use surface::{sample_grid, surface_colors};

/// Default density threshold σ of a NeRF's surface (one sample step of the lego config, 4/127,
/// then has opacity `1 − e^{−σΔ}` ≈ 0.27). Chosen as the threshold whose mesh of the shipped
/// model matches the test masks' silhouettes best, lower and higher ones both doing worse
/// (measured: docs/viewer-and-export.md#export-mesh-points-depth).
pub const DEFAULT_NERF_THRESHOLD: f64 = 10.0;

/// Samples per colour ray of a mesh vertex.
const COLOR_SAMPLES: usize = 16;

/// What `nerf export mesh` does.
#[derive(Debug, Clone)]
pub struct MeshOptions {
    /// Marching-cubes cells per side of the box (1 to [`limits::MESH_RESOLUTION`]).
    pub resolution: usize,
    /// The density at the surface: NeRF σ (default [`DEFAULT_NERF_THRESHOLD`]); for an SDF
    /// scene the homework's density in `(0, α)` (default α/2, the zero level of the SDF).
    pub threshold: Option<f64>,
    /// The PLY file to write.
    pub out: PathBuf,
}

/// What `nerf export mesh` made.
#[derive(Debug, Clone)]
pub struct MeshSummary {
    /// Vertices written.
    pub vertices: usize,
    /// Triangles written.
    pub faces: usize,
    /// The density threshold used.
    pub threshold: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Fails early (before any rendering) when `out`'s directory cannot be written or `out` is a
/// directory.
fn check_output_file(out: &Path) -> Result<()> {
    ensure!(
        !out.is_dir(),
        "{} is a directory, not a file",
        out.display()
    );
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty());
    prepare_out_dir(dir.unwrap_or(Path::new(".")))
}

/// The box meshed for an SDF: the shape's bounds grown by 10% and four β on every side.
fn sdf_box(volume: &SdfVolume) -> [f32; 6] {
    let half: [f32; 3] = match volume.sdf {
        Sdf::Box { side_lengths, .. } => side_lengths.map(|s| 0.5 * s.abs()),
        Sdf::Sphere { radius, .. } => [radius.abs(); 3],
    };
    let c = volume.sdf.center();
    let margin = 0.1 * half.iter().fold(0.0f32, |a, &b| a.max(b)) + 4.0 * volume.beta as f32;
    std::array::from_fn(|i| {
        let a = i % 3;
        c[a] + if i < 3 { -1.0 } else { 1.0 } * (half[a] + margin)
    })
}

/// The SDF's density sampled on the grid, as `−sdf` with the level where the homework's
/// density equals `threshold`.
fn sdf_grid(
    volume: &SdfVolume,
    dims: [usize; 3],
    threshold: f64,
    batch: usize,
) -> Result<(VolumeGrid, f32)> {
    let Some(s) = sdf_at_density(threshold, volume.alpha, volume.beta) else {
        bail!(
            "--threshold {threshold}: an SDF scene's density runs from 0 to alpha = {}, so the \
             threshold must lie strictly between",
            volume.alpha
        );
    };
    let scalar = |p: &[f32]| -> Result<Vec<f32>> {
        Ok(p.chunks_exact(3)
            .map(|q| -volume.sdf.distance([q[0], q[1], q[2]]))
            .collect())
    };
    // Without an occupancy grid every point is evaluated, so the empty value is never used.
    let grid = sample_grid(dims, sdf_box(volume), None, f32::MIN, batch, &scalar)?;
    Ok((grid, -s as f32))
}

/// The NeRF's σ on the grid over the config's occupancy-grid box (default ±1.5), evaluated
/// only in occupied cells.
fn nerf_grid(
    config: &Config,
    field: &dyn Field,
    dims: [usize; 3],
    batch: usize,
    device: &Device,
) -> Result<VolumeGrid> {
    let aabb = config
        .renderer
        .occupancy_grid
        .as_ref()
        .map_or(OccupancyGridConfig::default().aabb, |g| g.aabb)
        .map(|v| v as f32);
    let scalar = |p: &[f32]| -> Result<Vec<f32>> {
        let points = Tensor::from_slice(p, (p.len() / 3, 3), device)?;
        Ok(field.density(&points)?.flatten_all()?.to_vec1::<f32>()?)
    };
    sample_grid(dims, aabb, field.occupancy(), 0.0, batch, &scalar)
}

/// The largest value of a grid, for the error when no surface is found.
fn max_value(grid: &VolumeGrid) -> f32 {
    grid.values.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b))
}

/// `nerf export mesh`: marching cubes on the scene's density, vertex colours seen from outside
/// along the normal, written as a binary PLY.
pub fn export_mesh(
    config: &Config,
    checkpoint: Option<&Path>,
    options: &MeshOptions,
    device: &Device,
) -> Result<MeshSummary> {
    let start = Instant::now();
    let r = options.resolution;
    ensure!(
        (1..=limits::MESH_RESOLUTION).contains(&r),
        "--resolution must be 1 to {} (got {r})",
        limits::MESH_RESOLUTION
    );
    if let Some(t) = options.threshold {
        ensure!(
            t.is_finite(),
            "--threshold must be a finite number (got {t})"
        );
    }
    check_output_file(&options.out)?;
    let chunks = WorkChunks::from_env()?;
    let scene = load_scene_field(config, checkpoint, device)?;
    let dims = [r + 1; 3];
    let (grid, level, threshold) = match &scene {
        SceneField::Sdf { volume, .. } => {
            let t = options.threshold.unwrap_or(0.5 * volume.alpha);
            let (grid, level) = sdf_grid(volume, dims, t, chunks.grid_points)?;
            (grid, level, t)
        }
        SceneField::Nerf(field) => {
            let t = options.threshold.unwrap_or(DEFAULT_NERF_THRESHOLD);
            ensure!(t > 0.0, "--threshold must be a positive density (got {t})");
            (
                nerf_grid(config, field.as_ref(), dims, chunks.grid_points, device)?,
                t as f32,
                t,
            )
        }
    };
    let mesh = marching_cubes(&grid, level, limits::MESH_FACES)
        .with_context(|| format!("--resolution {r}, threshold {threshold}"))?;
    if mesh.faces.is_empty() {
        bail!(
            "no surface at threshold {threshold}: the density stays on one side of it in the \
             whole box (largest sampled value {})",
            max_value(&grid)
        );
    }
    let colors = mesh_colors(config, &scene, &mesh, &grid, chunks.rays, device)?;
    write_mesh_ply(&options.out, &mesh, &colors)?;
    Ok(MeshSummary {
        vertices: mesh.vertices.len(),
        faces: mesh.faces.len(),
        threshold,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Vertex colours: a short ray from two cells outside each vertex, inwards along its normal.
fn mesh_colors(
    config: &Config,
    scene: &SceneField,
    mesh: &TriMesh,
    grid: &VolumeGrid,
    band: usize,
    device: &Device,
) -> Result<Vec<[f32; 3]>> {
    let offset = 2.0 * grid.cell().iter().fold(0.0f32, |a, &b| a.max(b));
    surface_colors(
        scene.as_field(),
        &config.renderer()?,
        mesh,
        offset,
        COLOR_SAMPLES,
        band,
        device,
    )
}

/// Which views `nerf export points` and `nerf export depth` render.
#[derive(Debug, Clone)]
pub struct ViewSelection {
    /// The dataset split (NeRF scenes); SDF scenes use the config's surround cameras.
    pub split: Split,
    /// The dataset directory.
    pub data_dir: PathBuf,
    /// Only the first this many views.
    pub limit: Option<usize>,
}

/// The size the views of [`export_cameras`] are rendered at: the dataset's
/// ([`nerf::config::DataConfig::dataset_image_size`]) for a NeRF, `data.image_size` for an
/// SDF scene.
fn view_size(config: &Config, scene: &SceneField, views: &ViewSelection) -> Result<(usize, usize)> {
    match scene {
        SceneField::Nerf(_) => config
            .data
            .dataset_image_size(&views.data_dir, SizeUse::Scoring),
        SceneField::Sdf { .. } => Ok(config.image_size()),
    }
}

/// The named cameras to render: the split's frames (named by image file stem; a capture's in
/// the frame the checkpoint that [`Config::checkpoint`] picks for `checkpoint` stores) for a
/// NeRF, the surround cameras (`view_000`, …) for an SDF scene.
fn export_cameras(
    config: &Config,
    checkpoint: Option<&Path>,
    scene: &SceneField,
    views: &ViewSelection,
) -> Result<Vec<(String, Camera)>> {
    let mut cameras: Vec<(String, Camera)> = match scene {
        SceneField::Nerf(_) => nerf_views(config, checkpoint, views)?
            .into_iter()
            .map(|f| {
                let name = f
                    .file_path
                    .file_stem()
                    .map_or_else(|| "view".to_string(), |s| s.to_string_lossy().to_string());
                (name, f.camera)
            })
            .collect(),
        SceneField::Sdf { .. } => config
            .surround_cameras()
            .into_iter()
            .enumerate()
            .map(|(i, c)| (format!("view_{i:03}"), c.into()))
            .collect(),
    };
    cameras.truncate(views.limit.unwrap_or(usize::MAX));
    Ok(cameras)
}

/// The frames of the selected split, a capture's in the frame the checkpoint stores.
fn nerf_views(
    config: &Config,
    checkpoint: Option<&Path>,
    views: &ViewSelection,
) -> Result<Vec<nerf::io::dataset::Frame>> {
    let path = config.checkpoint(checkpoint);
    let stored = stored_transform(&path)?;
    let read = read_split_with(&views.data_dir, views.split, stored)?;
    note_scene_frame(&views.data_dir, &path, stored, read.normalisation.as_ref());
    Ok(read.frames)
}

/// Keeps the points inside `aabb` (`[min.., max..]`).
fn crop(cloud: ColoredPoints, aabb: [f64; 6]) -> ColoredPoints {
    let inside = |p: &[f32; 3]| (0..3).all(|a| (aabb[a]..=aabb[a + 3]).contains(&(p[a] as f64)));
    let (points, colors) = cloud
        .points
        .into_iter()
        .zip(cloud.colors)
        .filter(|(p, _)| inside(p))
        .unzip();
    ColoredPoints { points, colors }
}

/// Opacity a ray needs to give a point (nerfstudio's `ns-export pointcloud` keeps rays whose
/// accumulated weight exceeds 0.5).
pub const POINT_MIN_OPACITY: f32 = 0.5;

/// An error naming the limit when `views` views of `(w, h)` pixels have more rays than
/// [`limits::POINT_CLOUD_RAYS`] (each may give a point, and the cloud is held until written).
fn check_point_cloud_size(views: usize, (w, h): (usize, usize)) -> Result<()> {
    let rays = views.saturating_mul(w * h);
    ensure!(
        rays <= limits::POINT_CLOUD_RAYS,
        "{views} views of {w}x{h} pixels are {rays} rays, over the {} a point cloud may have \
         (fewer views with --limit, or a smaller data.image_size)",
        limits::POINT_CLOUD_RAYS
    );
    Ok(())
}

/// `nerf export points`: one point per opaque ray of every selected view at the config's
/// image size (cropped to the occupancy grid's box for a NeRF), written as a binary PLY.
/// Returns the number of points.
pub fn export_points(
    config: &Config,
    checkpoint: Option<&Path>,
    views: &ViewSelection,
    out: &Path,
    device: &Device,
) -> Result<usize> {
    check_output_file(out)?;
    let chunks = WorkChunks::from_env()?;
    let scene = load_scene_field(config, checkpoint, device)?;
    let cameras = export_cameras(config, checkpoint, &scene, views)?;
    let size = view_size(config, &scene, views)?;
    check_point_cloud_size(cameras.len(), size)?;
    let render = config.render_settings()?;
    let bar = progress_bar(cameras.len() as u64, "points");
    let mut cloud = ColoredPoints::default();
    for (_, camera) in &cameras {
        let pipeline = render.with(scene.as_field());
        let part = depth_points(
            &pipeline,
            camera,
            size,
            POINT_MIN_OPACITY,
            chunks.rays,
            device,
        )?;
        cloud.points.extend(part.points);
        cloud.colors.extend(part.colors);
        bar.inc(1);
    }
    bar.finish_and_clear();
    if let Some(g) = &config.renderer.occupancy_grid {
        cloud = crop(cloud, g.aabb);
    }
    if cloud.points.is_empty() {
        bail!("no ray of the {} views is opaque: no points", cameras.len());
    }
    write_points_ply(out, &cloud.points, &cloud.colors)?;
    Ok(cloud.points.len())
}

/// `nerf export depth`: for each selected view at the config's image size, `<name>.npy`
/// (`(H, W)` float32, the renderer's depth `Σ wᵢtᵢ`, as `nerf render --raw`) and `<name>.png`
/// (viridis after min–max normalisation, as `depth.png`). Returns the files written.
pub fn export_depth(
    config: &Config,
    checkpoint: Option<&Path>,
    views: &ViewSelection,
    out_dir: &Path,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    ensure!(
        !out_dir.is_file(),
        "{} is a file, not a directory",
        out_dir.display()
    );
    prepare_out_dir(out_dir)?;
    let scene = load_scene_field(config, checkpoint, device)?;
    let cameras = export_cameras(config, checkpoint, &scene, views)?;
    let render = config.render_settings()?;
    let (w, h) = view_size(config, &scene, views)?;
    let bar = progress_bar(cameras.len() as u64, "depth");
    // A view that fails takes the views written before it away with it.
    let written = write_all(|written| {
        for (name, camera) in &cameras {
            let view = render_view(&render.with(scene.as_field()), camera, (w, h), device)
                .with_context(|| format!("view {name}"))?;
            let npy = out_dir.join(format!("{name}.npy"));
            write_npy(&npy, &[h as u64, w as u64], &view.depth)?;
            written.push(npy);
            let png = out_dir.join(format!("{name}.png"));
            write_png(&png, &viridis_image(w, h, &view.depth)?)?;
            written.push(png);
            bar.inc(1);
        }
        Ok(())
    });
    bar.finish_and_clear();
    written
}
