//! Occupancy grid: which cells of the scene's bounding box can hold density, so the renderer
//! evaluates the field only there (empty-space skipping, as nerfacc's `OccGridEstimator`).
//!
//! The grid keeps, per cell, a running maximum of the field's density at points in the cell
//! (decayed by `decay` at every update, so cells that become empty during training are
//! released). A cell is occupied when that value exceeds `min(density_threshold, mean)`; the
//! threshold is the density at which one sample step has opacity `alpha_threshold`:
//! `σ = −ln(1 − alpha_threshold) / step`. Points outside the bounding box are empty.
//!
//! Cells are indexed `(ix · R + iy) · R + iz`, x slowest.
//!
//! With a scene contraction ([`Contraction::LInf`], unbounded scenes) the grid's box is in
//! contracted space, as the field's is: a point is contracted before its cell is looked up,
//! and a cell is probed at world points (its contracted points mapped back). The whole ray
//! is then tested sample by sample, and whole empty blocks are skipped only inside the
//! unit cube, where the contraction is the identity (elsewhere a block is not a box in the
//! world).

use std::collections::HashMap;

use anyhow::{ensure, Context, Result};

use candle_core::{Device, Tensor};
use nerf_core::contraction::Contraction;
use nerf_core::truncate::truncate_u32;
use rand::Rng;

/// Points evaluated per density batch when updating or building a grid.
const DENSITY_BATCH: usize = 1 << 16;

/// Cells per side of the blocks that ray marching skips whole ([`OccupancyGrid::empty_blocks`]).
pub(crate) const BLOCK: usize = 8;

/// Which blocks of `BLOCK`³ cells of a grid are empty (x slowest, as the cells).
#[derive(Debug, Clone, PartialEq)]
pub struct EmptyBlocks {
    /// Blocks per side, `ceil(R / BLOCK)`.
    pub per_side: usize,
    /// Per block: no occupied cell.
    pub empty: Vec<bool>,
}

/// Where one ray leaves the cells it crosses, from [`OccupancyGrid::ray_faces`]: per axis,
/// the exit face of cell 0 less the margin, relative to the origin, the cell size (0 on an
/// axis the ray does not move along, whose `first` is +∞) and `1 / direction`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RayFaces {
    first: [f64; 3],
    first_block: [f64; 3],
    size: [f64; 3],
    inverse_direction: [f64; 3],
}

impl RayFaces {
    /// The depth before which every sample past a point found in the cell at coordinates
    /// `cell` ([`OccupancyGrid::cell_coordinates`]) lies in that cell too (see
    /// [`OccupancyGrid::ray_faces`]).
    #[inline]
    pub(crate) fn exit(&self, cell: [usize; 3]) -> f64 {
        (0..3)
            .map(|k| (self.first[k] + cell[k] as f64 * self.size[k]) * self.inverse_direction[k])
            .fold(f64::INFINITY, f64::min)
    }

    /// [`RayFaces::exit`] for the block of [`BLOCK`]³ cells holding the cell at coordinates
    /// `cell` (past the grid's box where the last block is partial: no point there is
    /// occupied).
    #[inline]
    pub(crate) fn block_exit(&self, cell: [usize; 3]) -> f64 {
        (0..3)
            .map(|k| {
                let block = (cell[k] / BLOCK * BLOCK) as f64;
                (self.first_block[k] + block * self.size[k]) * self.inverse_direction[k]
            })
            .fold(f64::INFINITY, f64::min)
    }
}

impl EmptyBlocks {
    /// Whether the block holding the cell at coordinates `cell` has no occupied cell.
    #[inline]
    pub(crate) fn holds_empty(&self, cell: [usize; 3]) -> bool {
        let [x, y, z] = cell.map(|c| c / BLOCK);
        self.empty[(x * self.per_side + y) * self.per_side + z]
    }
}

/// The occupancy grid of one field.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// Cells per side `R`.
    pub resolution: usize,
    /// Lower corner `[x, y, z]` of the bounding box, in world units.
    pub aabb_min: [f32; 3],
    /// Upper corner `[x, y, z]` of the bounding box, in world units.
    pub aabb_max: [f32; 3],
    /// Density above which a cell counts as occupied (before the `mean` cap).
    pub density_threshold: f32,
    /// `R³` running maxima of the density seen in each cell.
    pub density: Vec<f32>,
    /// `R³` occupancy flags derived from `density`.
    pub occupied: Vec<bool>,
    /// How world points map into the space of the box (identity for bounded scenes).
    pub contraction: Contraction,
    /// `R³` flags of cells kept empty whatever the field holds there (the space around the
    /// training cameras, [`OccupancyGrid::clear_around_cameras`]); empty when there are none.
    pub kept_empty: Vec<bool>,
    /// Whether the far shell is kept occupied ([`OccupancyGrid::keep_far_shell`]).
    pub far_shell_kept: bool,
}

/// Density at which one step of `step` has opacity `alpha`: `−ln(1 − alpha) / step`.
pub fn density_threshold(alpha: f64, step: f64) -> f64 {
    -(1.0 - alpha).ln() / step
}

/// What an occupancy grid covers and when a cell counts as occupied.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGridParams {
    /// Cells per side.
    pub resolution: usize,
    /// `[min_x, min_y, min_z, max_x, max_y, max_z]`; outside it the field is taken as empty.
    pub aabb: [f64; 6],
    /// Density above which a cell counts as occupied (before the `mean` cap); see
    /// [`density_threshold`].
    pub density_threshold: f64,
    /// How world points map into the space `aabb` is in (the field's contraction).
    pub contraction: Contraction,
}

impl Default for OccupancyGridParams {
    /// The configs' defaults: 64³ cells over `[-1.5, 1.5]³` (the NeRF-synthetic scenes), a
    /// cell occupied where one cell-wide step would reach 1% opacity.
    fn default() -> Self {
        let aabb = [-1.5, -1.5, -1.5, 1.5, 1.5, 1.5];
        let resolution = 64;
        Self {
            resolution,
            aabb,
            density_threshold: density_threshold(0.01, (aabb[3] - aabb[0]) / resolution as f64),
            contraction: Contraction::None,
        }
    }
}

/// A field's density at points: `(M, 3)` → `(M, 1)`.
pub(crate) type DensityFn<'a> = &'a dyn Fn(&Tensor) -> Result<Tensor>;

/// The grid for a trained model: the one saved in the checkpoint's `occupancy.density` when
/// present and of the configured resolution, else built from the model's `density`
/// (`OccupancyGrid::build`). `tensors`: the checkpoint's, where `occupancy.density` is
/// `(R, R, R)` for resolution R.
pub fn grid_for_checkpoint(
    params: &OccupancyGridParams,
    tensors: &HashMap<String, Tensor>,
    density: DensityFn,
    device: &Device,
) -> Result<OccupancyGrid> {
    let r = params.resolution;
    if let Some(saved) = tensors
        .get(CHECKPOINT_KEY)
        .filter(|t| t.dims() == [r, r, r])
    {
        return OccupancyGrid::from_tensor(params, saved);
    }
    let start = std::time::Instant::now();
    let grid = OccupancyGrid::build(params, density, device)?;
    log::info!(
        "built a {r}^3 occupancy grid from the model in {:.1} s: {:.1}% of cells occupied",
        start.elapsed().as_secs_f64(),
        100.0 * grid.occupied_fraction()
    );
    Ok(grid)
}

/// A kept far shell's running density is held at least at this many times the grid's density
/// threshold ([`OccupancyGrid::refresh_occupied`]).
pub(crate) const FAR_SHELL_FLOOR: f32 = 2.0;

/// Name of the grid's tensor in a checkpoint.
pub const CHECKPOINT_KEY: &str = "occupancy.density";

impl OccupancyGrid {
    /// A grid with every cell occupied (nothing is skipped until the first update).
    pub fn new(params: &OccupancyGridParams) -> Result<Self> {
        let r = params.resolution;
        ensure!(r >= 1, "occupancy_grid.resolution must be at least 1");
        let [x0, y0, z0, x1, y1, z1] = params.aabb.map(|v| v as f32);
        ensure!(
            x0 < x1 && y0 < y1 && z0 < z1,
            "occupancy_grid.aabb must be [min_x, min_y, min_z, max_x, max_y, max_z] with min < max"
        );
        Ok(Self {
            resolution: r,
            aabb_min: [x0, y0, z0],
            aabb_max: [x1, y1, z1],
            density_threshold: params.density_threshold as f32,
            density: vec![f32::MAX; r * r * r],
            occupied: vec![true; r * r * r],
            contraction: params.contraction,
            kept_empty: Vec::new(),
            far_shell_kept: false,
        })
    }

    /// Number of cells, `R³`.
    pub fn n_cells(&self) -> usize {
        self.density.len()
    }

    /// Whether a cell holds density above the threshold: any occupied cell but a kept far
    /// shell, which is occupied whatever the field holds there.
    pub fn any_dense_cell(&self) -> bool {
        let kept = self.far_shell_kept;
        (0..self.n_cells()).any(|c| self.occupied[c] && !(kept && self.is_far_shell(c)))
    }

    /// Keeps a contracted grid's far shell (`OccupancyGrid::is_far_shell`) occupied from now
    /// on (nothing without a contraction). For photos whose far field is scene, not a backdrop
    /// (a room, a street): every ray then ends on samples of the far shell, so a ray through
    /// space the grid emptied still takes the colour the field learnt far behind it, where it
    /// would otherwise end on the background colour (black for such photos: square black
    /// holes in a room's walls where cells were dropped). Not for photos with a backdrop or
    /// alpha: the shell's last sample (its length 1e10) would then paint an opaque backdrop
    /// where the background should show.
    pub fn keep_far_shell(&mut self) {
        if self.contraction != Contraction::None {
            self.far_shell_kept = true;
            self.refresh_occupied();
        }
    }

    /// Whether `cell` is in the outermost layer of the grid: with a contraction, what lies
    /// farthest (beyond 1 / (cell side) of the unit cube).
    pub(crate) fn is_far_shell(&self, cell: usize) -> bool {
        let r = self.resolution;
        let i = [cell / (r * r), (cell / r) % r, cell % r];
        i.iter().any(|&k| k == 0 || k + 1 == r)
    }

    /// The cell holding point `p`, or `None` outside the bounding box.
    #[inline]
    pub(crate) fn cell_of(&self, p: [f32; 3]) -> Option<usize> {
        Some(self.cell_index(self.cell_coordinates(p)?))
    }

    /// The index of the cell at integer coordinates `[ix, iy, iz]` (each below `R`).
    #[inline]
    pub(crate) fn cell_index(&self, [x, y, z]: [usize; 3]) -> usize {
        let r = self.resolution;
        (x * r + y) * r + z
    }

    /// The integer coordinates `[ix, iy, iz]` of the cell holding world point `p` (contracted
    /// first when the grid is), or `None` outside the bounding box (or for NaN).
    #[inline]
    pub(crate) fn cell_coordinates(&self, p: [f32; 3]) -> Option<[usize; 3]> {
        let p = self.contraction.contract_f32(p);
        let r = self.resolution;
        let mut cell = [0; 3];
        for k in 0..3 {
            let (lo, hi) = (self.aabb_min[k], self.aabb_max[k]);
            let u = (p[k] - lo) / (hi - lo);
            // Also rejects NaN.
            if !(0.0..1.0).contains(&u) {
                return None;
            }
            cell[k] = (truncate_u32(u * r as f32) as usize).min(r - 1);
        }
        Some(cell)
    }

    /// Whether the field may have density at `p`.
    #[inline]
    pub fn is_occupied(&self, p: [f32; 3]) -> bool {
        self.cell_of(p).is_some_and(|c| self.occupied[c])
    }

    /// The depths `(enter, exit)` between which the ray `origin + t·direction` is inside the
    /// bounding box (the slab test, in f64), or `None` when it misses the box. With a
    /// contraction, the whole ray (`(−∞, ∞)`): the contracted box is not a world box.
    pub(crate) fn crossing(&self, origin: [f32; 3], direction: [f32; 3]) -> Option<(f64, f64)> {
        if self.contraction != Contraction::None {
            return Some((f64::NEG_INFINITY, f64::INFINITY));
        }
        let (mut enter, mut exit) = (f64::NEG_INFINITY, f64::INFINITY);
        for k in 0..3 {
            let (o, d) = (f64::from(origin[k]), f64::from(direction[k]));
            let (lo, hi) = (f64::from(self.aabb_min[k]), f64::from(self.aabb_max[k]));
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
                continue;
            }
            let (a, b) = ((lo - o) / d, (hi - o) / d);
            enter = enter.max(a.min(b));
            exit = exit.min(a.max(b));
        }
        (enter <= exit).then_some((enter, exit))
    }

    /// Which blocks of `BLOCK`³ cells hold no occupied cell, from the current flags.
    pub fn empty_blocks(&self) -> EmptyBlocks {
        let r = self.resolution;
        let per_side = r.div_ceil(BLOCK);
        let mut empty = vec![true; per_side * per_side * per_side];
        for (cell, _) in self.occupied.iter().enumerate().filter(|(_, o)| **o) {
            let [x, y, z] = [
                cell / (r * r) / BLOCK,
                (cell / r) % r / BLOCK,
                cell % r / BLOCK,
            ];
            empty[(x * per_side + y) * per_side + z] = false;
        }
        EmptyBlocks { per_side, empty }
    }

    /// When the cell at coordinates `cell` ([`OccupancyGrid::cell_coordinates`]) lies in an
    /// empty block of `blocks`, the depths `(enter, exit)` at which the ray
    /// `origin + t·direction` crosses that block's box (f64); else `None`. Samples strictly
    /// inside that depth range (with a margin for rounding) are in empty cells.
    pub(crate) fn empty_block_crossing(
        &self,
        blocks: &EmptyBlocks,
        cell: [usize; 3],
        origin: [f32; 3],
        direction: [f32; 3],
    ) -> Option<(f64, f64)> {
        let b = cell.map(|c| c / BLOCK);
        let n = blocks.per_side;
        if !blocks.empty[(b[0] * n + b[1]) * n + b[2]] {
            return None;
        }
        let size =
            |k: usize| f64::from(self.aabb_max[k] - self.aabb_min[k]) / self.resolution as f64;
        let bounds = |k: usize| {
            let lo = f64::from(self.aabb_min[k]) + (b[k] * BLOCK) as f64 * size(k);
            (lo, lo + BLOCK as f64 * size(k))
        };
        // Contracted: a block is a world box only inside the unit cube (the identity there).
        if self.contraction != Contraction::None
            && !(0..3).all(|k| {
                let (lo, hi) = bounds(k);
                lo >= -1.0 && hi <= 1.0
            })
        {
            return None;
        }
        let (mut enter, mut exit) = (f64::NEG_INFINITY, f64::INFINITY);
        for k in 0..3 {
            let (lo, hi) = bounds(k);
            let (o, d) = (f64::from(origin[k]), f64::from(direction[k]));
            if d != 0.0 {
                let (a, c) = ((lo - o) / d, (hi - o) / d);
                enter = enter.max(a.min(c));
                exit = exit.min(a.max(c));
            }
        }
        Some((enter, exit))
    }

    /// The faces of the cells the ray `origin + t·direction` crosses ([`RayFaces::exit`]);
    /// `None` with a contraction, where a cell is not a world box.
    ///
    /// Each exit face is moved into its cell by a margin above the rounding of `o + t·d` in
    /// f32 and of the cell lookup, so a sample before a cell's exit depth has every coordinate
    /// short of the cell's exit faces. Along each axis the f32 point and its cell index only
    /// move one way as `t` grows, so from a point found in a cell on, the samples before its
    /// exit depth stay in it: no face-parallel ray, however grazing, is misplaced (for it the
    /// depth comes out at or before the found point, and nothing is skipped).
    pub(crate) fn ray_faces(&self, origin: [f32; 3], direction: [f32; 3]) -> Option<RayFaces> {
        if self.contraction != Contraction::None {
            return None;
        }
        let extent = (0..3)
            .map(|k| {
                self.aabb_min[k]
                    .abs()
                    .max(self.aabb_max[k].abs())
                    .max(origin[k].abs())
            })
            .fold(0f32, f32::max);
        let rounding = 16.0 * f64::from(f32::EPSILON) * f64::from(extent);
        let mut faces = RayFaces {
            first: [f64::INFINITY; 3],
            first_block: [f64::INFINITY; 3],
            size: [0.0; 3],
            inverse_direction: [1.0; 3],
        };
        for k in 0..3 {
            let d = f64::from(direction[k]);
            if d == 0.0 || !d.is_finite() {
                continue;
            }
            let (lo, hi) = (f64::from(self.aabb_min[k]), f64::from(self.aabb_max[k]));
            let size = (hi - lo) / self.resolution as f64;
            let margin = 1e-3 * size + rounding;
            // Cell 0's exit face along the direction of travel, less the margin.
            let face = match d > 0.0 {
                true => lo + size - margin,
                false => lo + margin,
            };
            faces.first[k] = face - f64::from(origin[k]);
            // Block 0's: BLOCK cells further along a positive direction.
            let block_face = face
                + if d > 0.0 {
                    (BLOCK - 1) as f64 * size
                } else {
                    0.0
                };
            faces.first_block[k] = block_face - f64::from(origin[k]);
            faces.size[k] = size;
            faces.inverse_direction[k] = 1.0 / d;
        }
        Some(faces)
    }

    /// Fraction of cells marked occupied.
    pub fn occupied_fraction(&self) -> f64 {
        self.occupied.iter().filter(|o| **o).count() as f64 / self.n_cells() as f64
    }

    /// The world point at fractional position `u ∈ [0, 1]³` of cell `cell` (with a
    /// contraction, the position is in contracted space and mapped back).
    fn point_in_cell(&self, cell: usize, u: [f32; 3]) -> [f32; 3] {
        let r = self.resolution;
        let i = [cell / (r * r), (cell / r) % r, cell % r];
        self.world_point(std::array::from_fn(|k| {
            let size = (self.aabb_max[k] - self.aabb_min[k]) / r as f32;
            self.aabb_min[k] + (i[k] as f32 + u[k]) * size
        }))
    }

    /// The world point of a point `q` of the grid's space (itself without a contraction).
    fn world_point(&self, q: [f32; 3]) -> [f32; 3] {
        match self.contraction {
            Contraction::None => q,
            c => c.uncontract(q.map(f64::from)).map(|v| v as f32),
        }
    }

    /// Recomputes the flags: occupied where the running density exceeds
    /// `min(density_threshold, mean density)`, except in cells kept empty. A kept far shell
    /// ([`OccupancyGrid::keep_far_shell`]) has its running density held at
    /// [`FAR_SHELL_FLOOR`] times the threshold, so it is occupied (and stays so in a saved
    /// grid read back), and is left out of the mean, which then says what the scene holds.
    pub(crate) fn refresh_occupied(&mut self) {
        let floor = FAR_SHELL_FLOOR * self.density_threshold;
        let (mut sum, mut count) = (0.0f64, 0usize);
        for cell in 0..self.n_cells() {
            if self.far_shell_kept && self.is_far_shell(cell) {
                self.density[cell] = self.density[cell].max(floor);
            } else {
                sum += self.density[cell] as f64;
                count += 1;
            }
        }
        let mean = sum / count.max(1) as f64;
        let threshold = (self.density_threshold as f64).min(mean) as f32;
        for (o, &d) in self.occupied.iter_mut().zip(&self.density) {
            *o = d > threshold;
        }
        for (o, &kept) in self.occupied.iter_mut().zip(&self.kept_empty) {
            *o &= !kept;
        }
    }

    /// Keeps empty, from now on, every cell whose centre (a world point) lies within
    /// `fraction · |c|` of a camera centre `c`: the space around each camera, in proportion
    /// to its distance from the origin, where the normalised scene's centre is (`fraction` in
    /// [0, 1), so the centre stays clear). The renderer then never samples there, so the
    /// field cannot explain the backdrop with density in front of the cameras. Their running
    /// density becomes 0 (so a saved grid keeps them empty) and updates leave them alone.
    /// Returns how many cells are kept empty.
    pub fn clear_around_cameras(&mut self, centres: &[[f64; 3]], fraction: f64) -> usize {
        let n = self.n_cells();
        if self.kept_empty.len() != n {
            self.kept_empty = vec![false; n];
        }
        if fraction <= 0.0 {
            return self.kept_empty.iter().filter(|k| **k).count();
        }
        // (centre, squared radius) of each camera's ball.
        let balls: Vec<([f64; 3], f64)> = centres
            .iter()
            .map(|c| {
                (
                    *c,
                    (fraction * fraction) * c.iter().map(|v| v * v).sum::<f64>(),
                )
            })
            .collect();
        for cell in 0..n {
            let p = self.point_in_cell(cell, [0.5; 3]).map(f64::from);
            let inside = balls
                .iter()
                .any(|(c, r2)| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f64>() < *r2);
            if inside {
                self.kept_empty[cell] = true;
                self.density[cell] = 0.0;
            }
        }
        self.refresh_occupied();
        self.kept_empty.iter().filter(|k| **k).count()
    }

    /// One training-time update (nerfacc's schedule): during warm-up every cell, afterwards the
    /// occupied cells and a random quarter of all cells, each probed at one uniformly random
    /// point; `density = max(density · decay, probe)` for the probed cells.
    pub fn update(
        &mut self,
        density: DensityFn,
        warmup: bool,
        decay: f32,
        rng: &mut impl Rng,
        device: &Device,
    ) -> Result<()> {
        let n = self.n_cells();
        let mut cells: Vec<usize> = if warmup {
            (0..n).collect()
        } else {
            let mut c: Vec<usize> = (0..n).filter(|&i| self.occupied[i]).collect();
            c.extend((0..n / 4).map(|_| rng.random_range(0..n)));
            c
        };
        if !self.kept_empty.is_empty() {
            cells.retain(|&c| !self.kept_empty[c]);
        }
        cells.sort_unstable();
        cells.dedup();
        let points: Vec<[f32; 3]> = cells
            .iter()
            .map(|&c| self.point_in_cell(c, std::array::from_fn(|_| rng.random::<f32>())))
            .collect();
        let probes = evaluate_density(density, &points, device)?;
        for (&c, &d) in cells.iter().zip(&probes) {
            let old = if self.density[c] == f32::MAX {
                0.0
            } else {
                self.density[c] * decay
            };
            self.density[c] = old.max(d);
        }
        self.refresh_occupied();
        Ok(())
    }

    /// A grid for a trained model that has none: every cell is probed at its centre and its
    /// eight corners (shared with the neighbours), keeping the largest density.
    pub(crate) fn build(
        params: &OccupancyGridParams,
        density: DensityFn,
        device: &Device,
    ) -> Result<Self> {
        let mut grid = Self::new(params)?;
        let r = grid.resolution;
        let centres: Vec<[f32; 3]> = (0..grid.n_cells())
            .map(|c| grid.point_in_cell(c, [0.5; 3]))
            .collect();
        grid.density = evaluate_density(density, &centres, device)?;
        let rc = r + 1;
        let corners: Vec<[f32; 3]> = (0..rc * rc * rc)
            .map(|c| {
                let i = [c / (rc * rc), (c / rc) % rc, c % rc];
                grid.world_point(std::array::from_fn(|k| {
                    let size = (grid.aabb_max[k] - grid.aabb_min[k]) / r as f32;
                    grid.aabb_min[k] + i[k] as f32 * size
                }))
            })
            .collect();
        let corner_density = evaluate_density(density, &corners, device)?;
        for ix in 0..r {
            for iy in 0..r {
                for iz in 0..r {
                    let cell = (ix * r + iy) * r + iz;
                    for d in 0..8 {
                        let (dx, dy, dz) = (d >> 2, (d >> 1) & 1, d & 1);
                        let corner = ((ix + dx) * rc + iy + dy) * rc + iz + dz;
                        grid.density[cell] = grid.density[cell].max(corner_density[corner]);
                    }
                }
            }
        }
        grid.refresh_occupied();
        Ok(grid)
    }

    /// The running densities as a `(R, R, R)` tensor, for checkpoints.
    pub fn to_tensor(&self, device: &Device) -> Result<Tensor> {
        let r = self.resolution;
        let finite: Vec<f32> = self
            .density
            .iter()
            .map(|&d| if d == f32::MAX { f32::INFINITY } else { d })
            .collect();
        Ok(Tensor::from_vec(finite, (r, r, r), device)?)
    }

    /// Restores a grid saved with [`OccupancyGrid::to_tensor`].
    ///
    /// `density`: `(R, R, R)` with `R = params.resolution`.
    pub fn from_tensor(params: &OccupancyGridParams, density: &Tensor) -> Result<Self> {
        let mut grid = Self::new(params)?;
        let r = grid.resolution;
        ensure!(
            density.dims() == [r, r, r],
            "occupancy grid of shape {:?} does not match renderer.occupancy_grid.resolution {r}",
            density.dims()
        );
        grid.density = density
            .flatten_all()?
            .to_vec1::<f32>()
            .context("occupancy grid")?
            .into_iter()
            .map(|d| if d == f32::INFINITY { f32::MAX } else { d })
            .collect();
        // A far shell kept in training is saved at its floor or above, every cell of it.
        let floor = FAR_SHELL_FLOOR * grid.density_threshold;
        grid.far_shell_kept = grid.contraction != Contraction::None
            && (0..grid.n_cells())
                .filter(|&c| grid.is_far_shell(c))
                .all(|c| grid.density[c] >= floor);
        grid.refresh_occupied();
        Ok(grid)
    }
}

/// The field's density at `points`, in batches.
fn evaluate_density(density: DensityFn, points: &[[f32; 3]], device: &Device) -> Result<Vec<f32>> {
    let mut out = Vec::with_capacity(points.len());
    for chunk in points.chunks(DENSITY_BATCH) {
        let flat: Vec<f32> = chunk.iter().flatten().copied().collect();
        let t = Tensor::from_vec(flat, (chunk.len(), 3), device)?;
        out.extend(density(&t)?.flatten_all()?.to_vec1::<f32>()?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(resolution: usize, density_threshold: f64) -> OccupancyGridParams {
        OccupancyGridParams {
            resolution,
            aabb: [-1.0, -2.0, -1.0, 1.0, 2.0, 3.0],
            density_threshold,
            contraction: Contraction::None,
        }
    }

    #[test]
    fn cells_cover_the_box_and_nothing_else() {
        let g = OccupancyGrid::new(&config(4, 1.0)).unwrap();
        assert_eq!(g.cell_of([-1.0, -2.0, -1.0]), Some(0));
        assert_eq!(g.cell_of([0.99, 1.99, 2.99]), Some(63));
        // x slowest: x in the second quarter → 16.
        assert_eq!(g.cell_of([-0.4, -1.9, -0.9]), Some(16));
        assert_eq!(g.cell_of([-0.9, -1.9, 0.1]), Some(1));
        assert_eq!(g.cell_of([-0.9, -1.9, 1.1]), Some(2));
        for p in [
            [1.0, 0.0, 0.0],
            [0.0, -2.1, 0.0],
            [0.0, 0.0, 3.5],
            [f32::NAN, 0.0, 0.0],
        ] {
            assert_eq!(g.cell_of(p), None, "{p:?}");
            assert!(!g.is_occupied(p));
        }
        for c in [0, 5, 21, 63] {
            let p = g.point_in_cell(c, [0.5; 3]);
            assert_eq!(g.cell_of(p), Some(c));
        }
    }

    #[test]
    fn threshold_is_capped_by_the_mean() {
        let mut g = OccupancyGrid::new(&config(2, 10.0)).unwrap();
        g.density = vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 100.0];
        g.refresh_occupied();
        // mean = 12.6 > 10: the threshold 10 applies.
        assert_eq!(
            g.occupied,
            [false, false, false, false, false, false, false, true]
        );
        g.density = vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0];
        g.refresh_occupied();
        // mean = 0.375 < 10: cells above the mean stay occupied.
        assert_eq!(
            g.occupied,
            [false, false, false, false, false, false, true, true]
        );
    }

    #[test]
    fn threshold_matches_the_alpha_definition() {
        let sigma = density_threshold(0.01, 0.5);
        assert!(((1.0 - (-sigma * 0.5).exp()) - 0.01).abs() < 1e-12);
    }

    #[test]
    fn tensor_round_trip() {
        let cfg = config(3, 0.5);
        let mut g = OccupancyGrid::new(&cfg).unwrap();
        for (i, d) in g.density.iter_mut().enumerate() {
            *d = i as f32 * 0.1;
        }
        g.density[4] = f32::MAX;
        g.refresh_occupied();
        let t = g.to_tensor(&Device::Cpu).unwrap();
        let back = OccupancyGrid::from_tensor(&cfg, &t).unwrap();
        assert_eq!(back, g);
        assert!(OccupancyGrid::from_tensor(&config(4, 0.5), &t).is_err());
    }
}

#[cfg(test)]
#[path = "occupancy_shell_tests.rs"]
mod shell_tests;

#[cfg(test)]
mod build_tests {
    use super::*;

    /// A ball of density `3 − 4|p|²` (clamped at 0): dense at the centre, empty at the edges.
    fn ball(points: &Tensor) -> Result<Tensor> {
        Ok(points.sqr()?.sum_keepdim(1)?.affine(-4.0, 3.0)?.relu()?)
    }

    #[test]
    fn build_marks_every_cell_whose_centre_is_dense() {
        let settings = |density_threshold| OccupancyGridParams {
            resolution: 6,
            aabb: [-1.5, -1.5, -1.5, 1.5, 1.5, 1.5],
            density_threshold,
            contraction: Contraction::None,
        };
        let centres: Vec<[f32; 3]> = {
            let g = OccupancyGrid::new(&settings(0.0)).unwrap();
            (0..g.n_cells())
                .map(|c| g.point_in_cell(c, [0.5; 3]))
                .collect()
        };
        let density = evaluate_density(&ball, &centres, &Device::Cpu).unwrap();
        let mut sorted = density.clone();
        sorted.sort_by(f32::total_cmp);
        assert!(
            sorted[0] < sorted[sorted.len() - 1],
            "the densities must differ"
        );
        // A threshold between the densities, so that some cells are empty and some not.
        let threshold = sorted[sorted.len() * 3 / 4] as f64;
        let grid = OccupancyGrid::build(&settings(threshold), &ball, &Device::Cpu).unwrap();
        let mean = grid.density.iter().map(|&d| d as f64).sum::<f64>() / grid.n_cells() as f64;
        let effective = threshold.min(mean) as f32;
        for (c, d) in density.iter().enumerate() {
            // The probe maximum includes the centre.
            assert!(grid.density[c] >= *d);
            if *d > effective {
                assert!(grid.occupied[c], "cell {c}");
            }
        }
        let f = grid.occupied_fraction();
        assert!(f > 0.0 && f < 1.0, "{f}");
    }
}
