//! A field made into a surface: its density sampled on a grid (for marching cubes), and the
//! colour of surface points as a camera just outside would see them.

use anyhow::{ensure, Result};
use candle_core::{Device, Tensor};

use crate::core::marching_cubes::VolumeGrid;
use crate::core::rays::Rays;
use crate::render::field::Field;
use crate::render::occupancy::OccupancyGrid;
use crate::render::renderer::VolumeRenderer;
use crate::render::sampler::StratifiedSampler;

/// Grid points evaluated per call of the scalar function.
const BATCH: usize = 1 << 16;

/// Samples `scalar` at the `dims` grid points spanning `aabb` (`[min_x, min_y, min_z, max_x,
/// max_y, max_z]`; x fastest, as [`VolumeGrid`]).
///
/// `scalar` takes `(M, 3)` points as a flat row-major slice and returns their M values. With an
/// `occupancy` grid, points outside its occupied cells (and outside its box) are not evaluated
/// and get `empty`: the renderer never evaluates the field there either.
pub fn sample_grid(
    dims: [usize; 3],
    aabb: [f32; 6],
    occupancy: Option<&OccupancyGrid>,
    empty: f32,
    scalar: &dyn Fn(&[f32]) -> Result<Vec<f32>>,
) -> Result<VolumeGrid> {
    let mut grid = VolumeGrid {
        dims,
        aabb,
        values: vec![empty; dims.iter().product()],
    };
    let [nx, ny, _] = dims;
    let occupied = |idx: usize| {
        let p = grid.point(idx % nx, (idx / nx) % ny, idx / (nx * ny));
        (occupancy.is_none_or(|o| o.is_occupied(p))).then_some((idx, p))
    };
    let wanted: Vec<(usize, [f32; 3])> = (0..grid.values.len()).filter_map(occupied).collect();
    for batch in wanted.chunks(BATCH) {
        let flat: Vec<f32> = batch.iter().flat_map(|(_, p)| *p).collect();
        let values = scalar(&flat)?;
        ensure!(
            values.len() == batch.len(),
            "the field gave {} values for {} points",
            values.len(),
            batch.len()
        );
        for ((idx, _), v) in batch.iter().zip(values) {
            grid.values[*idx] = v;
        }
    }
    Ok(grid)
}

/// The colour of each surface point seen from outside along its normal: a ray from
/// `vertex + offset · normal` towards `−normal`, through `n_samples` samples over `2 · offset`,
/// volume-rendered and divided by its opacity (so a surface that is not quite opaque over that
/// short ray keeps its colour instead of fading to the background).
///
/// `vertices`, `normals`: N points and unit normals; returns N colours in `[0, 1]`.
pub fn surface_colors(
    field: &dyn Field,
    renderer: &VolumeRenderer,
    vertices: &[[f32; 3]],
    normals: &[[f32; 3]],
    offset: f32,
    n_samples: usize,
    device: &Device,
) -> Result<Vec<[f32; 3]>> {
    ensure!(vertices.len() == normals.len(), "one normal per vertex");
    ensure!(
        offset > 0.0 && offset.is_finite(),
        "offset must be positive"
    );
    if vertices.is_empty() {
        return Ok(Vec::new());
    }
    let sampler = StratifiedSampler::new(n_samples, 0.0, 2.0 * offset as f64)?;
    let n = vertices.len();
    let origins: Vec<f32> = vertices
        .iter()
        .zip(normals)
        .flat_map(|(v, nrm)| [0, 1, 2].map(|a| v[a] + offset * nrm[a]))
        .collect();
    let directions: Vec<f32> = normals.iter().flat_map(|nrm| nrm.map(|c| -c)).collect();
    let rays = Rays {
        origins: Tensor::from_vec(origins, (n, 3), device)?,
        directions: Tensor::from_vec(directions, (n, 3), device)?,
    };
    // On black, so that dividing by the opacity recovers the surface colour.
    let black = VolumeRenderer {
        white_background: false,
        ..*renderer
    };
    let out = black.render(field, &sampler, &rays, None)?;
    let color = out.color.flatten_all()?.to_vec1::<f32>()?;
    let opacity = out.opacity.flatten_all()?.to_vec1::<f32>()?;
    Ok(color
        .chunks_exact(3)
        .zip(opacity)
        .map(|(c, a)| {
            let scale = if a > 1e-3 { 1.0 / a } else { 1.0 };
            [0, 1, 2].map(|k| (c[k] * scale).clamp(0.0, 1.0))
        })
        .collect())
}
