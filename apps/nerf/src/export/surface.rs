//! A field made into a surface: its density sampled on a grid (for marching cubes), and the
//! colour of surface points as a camera just outside would see them.

use anyhow::{ensure, Result};
use candle_core::{Device, Tensor};

use nerf::core::marching_cubes::{TriMesh, VolumeGrid};
use nerf::core::rays::Rays;
use nerf::render::bands::pixel_bands;
use nerf::render::field::Field;
use nerf::render::occupancy::OccupancyGrid;
use nerf::render::renderer::{VolumeRenderer, BLACK};
use nerf::render::sampler::StratifiedSampler;
use nerf::render::view::Pipeline;

/// Samples `scalar` at the `dims` grid points spanning `aabb` (`[min_x, min_y, min_z, max_x,
/// max_y, max_z]`; x fastest, as [`VolumeGrid`]), `batch` points per call (at least 1).
///
/// `scalar` takes `(M, 3)` points as a flat row-major slice and returns their M values. With an
/// `occupancy` grid, points outside its occupied cells (and outside its box) are not evaluated
/// and get `empty`: the renderer never evaluates the field there either. The points evaluated
/// are gathered as the grid is walked, so besides the grid only one batch is held.
pub fn sample_grid(
    dims: [usize; 3],
    aabb: [f32; 6],
    occupancy: Option<&OccupancyGrid>,
    empty: f32,
    batch: usize,
    scalar: &dyn Fn(&[f32]) -> Result<Vec<f32>>,
) -> Result<VolumeGrid> {
    let batch = batch.max(1);
    let mut grid = VolumeGrid {
        dims,
        aabb,
        values: vec![empty; dims.iter().product()],
    };
    let [nx, ny, _] = dims;
    let (mut index, mut flat) = (Vec::with_capacity(batch), Vec::with_capacity(3 * batch));
    for idx in 0..grid.values.len() {
        let p = grid.point(idx % nx, (idx / nx) % ny, idx / (nx * ny));
        if occupancy.is_none_or(|o| o.is_occupied(p)) {
            index.push(idx);
            flat.extend(p);
        }
        if index.len() == batch || (idx + 1 == grid.values.len() && !index.is_empty()) {
            let values = scalar(&flat)?;
            ensure!(
                values.len() == index.len(),
                "the field gave {} values for {} points",
                values.len(),
                index.len()
            );
            for (&i, v) in index.iter().zip(values) {
                grid.values[i] = v;
            }
            index.clear();
            flat.clear();
        }
    }
    Ok(grid)
}

/// The colour of each surface point seen from outside along its normal: a ray from
/// `vertex + offset · normal` towards `−normal`, through `n_samples` samples over `2 · offset`,
/// volume-rendered and divided by its opacity (so a surface that is not quite opaque over that
/// short ray keeps its colour instead of fading to the background).
///
/// `mesh`: N vertices and unit normals; returns N colours in `[0, 1]`. The rays are made and
/// rendered about `band` at a time (whole renderer chunks, so the colours do not depend on
/// it).
pub fn surface_colors(
    field: &dyn Field,
    renderer: &VolumeRenderer,
    mesh: &TriMesh,
    offset: f32,
    n_samples: usize,
    band: usize,
    device: &Device,
) -> Result<Vec<[f32; 3]>> {
    let (vertices, normals) = (&mesh.vertices, &mesh.normals);
    ensure!(vertices.len() == normals.len(), "one normal per vertex");
    ensure!(
        offset > 0.0 && offset.is_finite(),
        "offset must be positive"
    );
    if vertices.is_empty() {
        return Ok(Vec::new());
    }
    let sampler = StratifiedSampler::new(n_samples, 0.0, 2.0 * offset as f64)?;
    // On black, so that dividing by the opacity recovers the surface colour.
    let black = VolumeRenderer {
        background: BLACK,
        ..*renderer
    };
    let band = Pipeline::new(field, &sampler, &black).rays_per_band(band);
    let mut colors = Vec::with_capacity(vertices.len());
    for pixels in pixel_bands(vertices.len(), band) {
        let (v, nrm) = (&vertices[pixels.clone()], &normals[pixels]);
        let n = v.len();
        let origins: Vec<f32> = v
            .iter()
            .zip(nrm)
            .flat_map(|(v, nrm)| [0, 1, 2].map(|a| v[a] + offset * nrm[a]))
            .collect();
        let directions: Vec<f32> = nrm.iter().flat_map(|nrm| nrm.map(|c| -c)).collect();
        let rays = Rays {
            origins: Tensor::from_vec(origins, (n, 3), device)?,
            directions: Tensor::from_vec(directions, (n, 3), device)?,
            camera_index: None,
        };
        let out = black.render(field, &sampler, &rays, None)?;
        let color = out.color.flatten_all()?.to_vec1::<f32>()?;
        let opacity = out.opacity.flatten_all()?.to_vec1::<f32>()?;
        colors.extend(color.chunks_exact(3).zip(opacity).map(|(c, a)| {
            let scale = if a > 1e-3 { 1.0 / a } else { 1.0 };
            [0, 1, 2].map(|k| (c[k] * scale).clamp(0.0, 1.0))
        }));
    }
    Ok(colors)
}
