//! Evaluating a field only at the samples that can contribute: empty-space skipping with an
//! [`crate::render::occupancy::OccupancyGrid`] and early ray termination.
//!
//! The samples of a ray that lie in occupied cells are visited in segments, front to back:
//! [`segment_sizes`] of them per ray (4, 4, 8, then 16 at a time), so that most rays, which
//! end within a few samples of the surface, cost a few field calls. In each segment the field
//! is evaluated at the next occupied samples of still-live rays, as one packed batch. After a
//! segment, a ray whose transmittance `exp(−Σ τ)` has fallen below the early-termination
//! threshold is dropped. The packed densities and colours are then composited where they are
//! ([`crate::kernels::composite::composite_packed`], forward and backward over the evaluated
//! samples only), or, by its tensor-op twin, scattered into dense `(N, S, ·)` tensors with
//! zeros at skipped samples for the ordinary compositing: a skipped sample has σ = 0, so its
//! weight is exactly 0, and the two agree bit for bit.
//!
//! What that changes against dense rendering: samples in cells marked empty (density below the
//! grid's threshold when it was last probed) and samples behind the termination point, whose
//! weights sum to at most the threshold. Gradients flow to the evaluated samples, so training
//! and rendering share this path; which samples are kept is decided from values, as in
//! nerfacc.

use anyhow::Result;
use candle_core::{DType, Tensor};
use rayon::prelude::*;

use crate::core::rays::Rays;
use crate::core::volume::{clamped_optical_depth, spacing};
use crate::kernels::composite::{composite_packed, Composited, PackedValues};
use crate::render::field::{Field, FieldOutput};
use crate::render::occupancy::{EmptyBlocks, OccupancyGrid};

/// The most occupied samples per ray evaluated between early-termination checks.
pub const SEGMENT: usize = 16;

/// How many occupied samples per ray the `k`-th segment takes: 4, 4, 8, then [`SEGMENT`].
pub fn segment_sizes(k: usize) -> usize {
    match k {
        0 | 1 => 4,
        2 => 8,
        _ => SEGMENT,
    }
}

/// The most samples per ray evaluated in one batch: [`SEGMENT`] with early termination, all
/// of them without (there is nothing to check between segments).
pub fn segment_length(n_pts_per_ray: usize, early_termination: f64) -> usize {
    if early_termination > 0.0 {
        SEGMENT.min(n_pts_per_ray)
    } else {
        n_pts_per_ray
    }
}

/// How many samples a render drew, how many it tested against the occupancy grid, and at how
/// many the field was evaluated.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SampleCounts {
    /// Samples drawn (rays × samples per ray).
    pub total: usize,
    /// Samples tested against the occupancy grid: those that can lie in its box, as far as
    /// each ray stayed live (without a grid, every sample up to where the ray ended).
    pub examined: usize,
    /// Samples at which the field was evaluated.
    pub evaluated: usize,
}

impl SampleCounts {
    /// The fraction of drawn samples at which the field was evaluated (0 when none were drawn).
    pub fn evaluated_fraction(&self) -> f64 {
        self.evaluated as f64 / self.total.max(1) as f64
    }

    /// Counts of a dense evaluation of `total` samples.
    pub fn dense(total: usize) -> Self {
        Self {
            total,
            examined: total,
            evaluated: total,
        }
    }
}

impl std::ops::Add for SampleCounts {
    type Output = Self;

    fn add(self, other: Self) -> Self {
        Self {
            total: self.total + other.total,
            examined: self.examined + other.examined,
            evaluated: self.evaluated + other.evaluated,
        }
    }
}

/// Evaluates `field` at the samples that can contribute (see the module), packed: the flat
/// indices of the evaluated samples and the field's values there, by segment.
///
/// The samples are marched, not materialised: each ray's points `o + t·d` are formed only
/// where they are tested, from the first sample that can lie in the grid's bounding box
/// ([`OccupancyGrid::crossing`]) and only as far as the ray is still live, so a ray that
/// misses the box costs nothing and one that ends at a surface is not tested behind it.
///
/// `rays`: N rays; `lengths`: each ray's sample depths `(N, S, 1)`, increasing, or `(1, S, 1)`
/// depths shared by all rays.
pub fn evaluate_packed(
    field: &dyn Field,
    early_termination: f64,
    rays: &Rays,
    lengths: &Tensor,
) -> Result<PackedSamples> {
    let (rows, s, _) = lengths.dims3()?;
    let n = rays.len();
    anyhow::ensure!(
        rows == n || rows == 1,
        "sample lengths have {rows} rows for {n} rays"
    );
    // Ray `ray`'s depths start at `ray · stride` (0 when shared).
    let stride = if rows == 1 { 0 } else { s };
    let device = lengths.device();
    let lengths = lengths
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let grid = field.occupancy().map(|grid| MarchGrid {
        grid,
        blocks: grid.empty_blocks(),
    });
    let grid = grid.as_ref();
    let mut marches = start_marches(grid, rays, &lengths, stride, s)?;
    // A ray is live while its optical depth so far is below −ln(threshold).
    let depth_limit = if early_termination > 0.0 {
        -(early_termination.ln()) as f32
    } else {
        f32::INFINITY
    };
    let mut ray_depth = vec![0f32; n];
    let mut counts = SampleCounts {
        total: n * s,
        ..SampleCounts::default()
    };
    let mut all_index: Vec<u32> = Vec::new();
    let mut densities = Vec::new();
    let mut colours = Vec::new();
    for k in 0.. {
        let size = if early_termination > 0.0 {
            segment_sizes(k)
        } else {
            s
        };
        let live: Vec<bool> = ray_depth.iter().map(|&d| d < depth_limit).collect();
        let (index, points, ray_index) =
            march_segment(&mut marches, &live, grid, &lengths, stride, s, size);
        if index.is_empty() {
            break;
        }
        let m = index.len();
        let (density, colour) = field.evaluate_packed(
            &Tensor::from_vec(points, (m, 3), device)?,
            &Tensor::from_vec(ray_index, m, device)?,
            &rays.directions,
        )?;
        if depth_limit.is_finite() {
            let values = density.flatten_all()?.to_vec1::<f32>()?;
            for (&k, &sigma) in index.iter().zip(&values) {
                let (ray, i) = (k as usize / s, k as usize % s);
                let delta = spacing(&lengths[ray * stride..ray * stride + s], i);
                ray_depth[ray] += clamped_optical_depth(sigma, delta);
            }
        }
        all_index.extend(index);
        densities.push(density);
        colours.push(colour);
    }
    counts.evaluated = all_index.len();
    counts.examined = marches.iter().map(|m| m.examined).sum();
    Ok(PackedSamples {
        rays: n,
        per_ray: s,
        index: all_index,
        densities,
        colours,
        counts,
    })
}

/// One [`RayMarch`] per ray of `rays`; ray `r`'s `s` depths start at `lengths[r · stride]`.
fn start_marches(
    grid: Option<&MarchGrid>,
    rays: &Rays,
    lengths: &[f32],
    stride: usize,
    s: usize,
) -> Result<Vec<RayMarch>> {
    let f32_values = |t: &Tensor| -> Result<Vec<f32>> {
        Ok(t.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?)
    };
    let (origins, directions) = (f32_values(&rays.origins)?, f32_values(&rays.directions)?);
    Ok((0..rays.len())
        .map(|ray| {
            let t = &lengths[ray * stride..ray * stride + s];
            let (o, d) = (&origins[3 * ray..], &directions[3 * ray..]);
            RayMarch::new(grid, [o[0], o[1], o[2]], [d[0], d[1], d[2]], t)
        })
        .collect())
}

/// The next `size` occupied samples of every `live` ray, marched in parallel blocks of rays
/// and joined in ray order: flat sample indices `ray · S + i`, points (3 values each) and ray
/// indices. `lengths`: ray `r`'s `S` depths start at `r · stride`.
fn march_segment(
    marches: &mut [RayMarch],
    live: &[bool],
    grid: Option<&MarchGrid>,
    lengths: &[f32],
    stride: usize,
    s: usize,
    size: usize,
) -> (Vec<u32>, Vec<f32>, Vec<u32>) {
    let parts: Vec<Segment> = marches
        .par_chunks_mut(MARCH_BLOCK)
        .enumerate()
        .map(|(b, block)| {
            let mut part = Segment::default();
            for (j, march) in block.iter_mut().enumerate() {
                let ray = b * MARCH_BLOCK + j;
                if !live[ray] {
                    continue;
                }
                let t = &lengths[ray * stride..ray * stride + s];
                for _ in 0..size {
                    let Some((i, p)) = march.next_occupied(grid, t) else {
                        break;
                    };
                    part.index.push((ray * s + i) as u32);
                    part.points.extend_from_slice(&p);
                    part.ray_index.push(ray as u32);
                }
            }
            part
        })
        .collect();
    Segment::join(parts)
}

/// Rays marched together by one task.
const MARCH_BLOCK: usize = 512;

/// The samples one block of rays contributes to a segment: flat sample indices, points
/// (3 values each) and ray indices.
#[derive(Default)]
struct Segment {
    index: Vec<u32>,
    points: Vec<f32>,
    ray_index: Vec<u32>,
}

impl Segment {
    /// The parts' samples, concatenated in order.
    fn join(parts: Vec<Segment>) -> (Vec<u32>, Vec<f32>, Vec<u32>) {
        let mut all = Segment::default();
        for part in parts {
            all.index.extend(part.index);
            all.points.extend(part.points);
            all.ray_index.extend(part.ray_index);
        }
        (all.index, all.points, all.ray_index)
    }
}

/// The grid a march tests samples against, and its empty blocks.
struct MarchGrid<'a> {
    grid: &'a OccupancyGrid,
    blocks: EmptyBlocks,
}

/// Depth margin, in world units, kept between a skipped sample and the edge of the empty
/// block it was skipped in (far above f32 rounding of points; far below sample spacings).
const BLOCK_MARGIN: f64 = 1e-4;

/// One ray's walk over its samples, front to back: the next sample to test, the end of the
/// samples that can lie in the grid's box, and how many were tested.
struct RayMarch {
    origin: [f32; 3],
    direction: [f32; 3],
    next: usize,
    end: usize,
    examined: usize,
}

impl RayMarch {
    /// The walk over depths `t` (increasing) of the ray `origin + t·direction`: every sample
    /// without a grid, else those that can lie in its box, one sample of margin either side
    /// for rounding (the exact test is [`OccupancyGrid::is_occupied`] at each point).
    fn new(grid: Option<&MarchGrid>, origin: [f32; 3], direction: [f32; 3], t: &[f32]) -> Self {
        let (next, end) = match grid.map(|g| g.grid.crossing(origin, direction)) {
            None => (0, t.len()),
            Some(None) => (0, 0),
            Some(Some((enter, exit))) => (
                t.partition_point(|&v| f64::from(v) < enter)
                    .saturating_sub(1),
                (t.partition_point(|&v| f64::from(v) <= exit) + 1).min(t.len()),
            ),
        };
        Self {
            origin,
            direction,
            next,
            end,
            examined: 0,
        }
    }

    /// The next sample in an occupied cell (all samples without a grid): its index along the
    /// ray and its point `o + t·d` (the same f32 arithmetic as
    /// [`crate::kernels::sample_points`]), or `None` when the ray has no more. Samples in an
    /// empty block are passed over without a test, except within [`BLOCK_MARGIN`] of its
    /// faces; the result is exactly the per-sample test's.
    fn next_occupied(&mut self, grid: Option<&MarchGrid>, t: &[f32]) -> Option<(usize, [f32; 3])> {
        while self.next < self.end {
            let i = self.next;
            self.next += 1;
            self.examined += 1;
            let p = std::array::from_fn(|k| self.origin[k] + t[i] * self.direction[k]);
            let Some(g) = grid else {
                return Some((i, p));
            };
            // [`OccupancyGrid::is_occupied`], keeping the cell for the block test.
            let Some(cell) = g.grid.cell_coordinates(p) else {
                continue;
            };
            if g.grid.occupied[g.grid.cell_index(cell)] {
                return Some((i, p));
            }
            let crossing =
                g.grid
                    .empty_block_crossing(&g.blocks, cell, self.origin, self.direction);
            if let Some((enter, exit)) = crossing {
                while self.next < self.end {
                    let v = f64::from(t[self.next]);
                    if v <= enter + BLOCK_MARGIN || v >= exit - BLOCK_MARGIN {
                        break;
                    }
                    self.next += 1;
                }
            }
        }
        None
    }
}

/// The field's values at the samples [`evaluate_packed`] chose.
pub struct PackedSamples {
    /// Rays `N`.
    pub rays: usize,
    /// Samples per ray `S`.
    pub per_ray: usize,
    /// Flat sample index `ray · S + i` of each evaluated sample, in evaluation order.
    pub index: Vec<u32>,
    /// Densities `(M_k, 1)` per segment, in the order of `index`.
    pub densities: Vec<Tensor>,
    /// Colours `(M_k, 3)` per segment, in the order of `index`.
    pub colours: Vec<Tensor>,
    /// How many samples were drawn, tested and evaluated.
    pub counts: SampleCounts,
}

impl PackedSamples {
    /// Whether any value is tracked by autograd (training), so that the dense,
    /// differentiable path must composite it.
    pub fn tracks_gradient(&self) -> bool {
        self.densities
            .iter()
            .chain(&self.colours)
            .any(|t| t.track_op())
    }

    /// Colour `(N, 3)`, depth and opacity `(N, 1)` composited straight from the packed values
    /// ([`composite_packed`]; differentiable), given every sample's `lengths` `(N, S, 1)` (or
    /// `(1, S, 1)` shared by all rays).
    pub fn composite(&self, lengths: &Tensor) -> Result<Composited> {
        let device = lengths.device();
        let values = PackedValues {
            index: self.index.clone(),
            n_rays: self.rays,
            density: concat_segments(&self.densities, 1, device)?,
            feature: concat_segments(&self.colours, 3, device)?,
        };
        composite_packed(values, lengths)
    }

    /// The values scattered into dense density `(N, S, 1)` and colour `(N, S, 3)`, zeros at
    /// skipped samples (differentiable).
    pub fn scatter(self, device: &candle_core::Device) -> Result<FieldOutput> {
        scatter_packed(
            self.rays,
            self.per_ray,
            self.index,
            &self.densities,
            &self.colours,
            device,
        )
    }
}

/// Scatters packed densities `(M, 1)` and colours `(M, 3)`, given in segments (in the order
/// of `index`, flat sample indices `ray · S + i`), into dense `(N, S, 1)` and `(N, S, 3)`
/// tensors, zeros elsewhere ([`crate::kernels::composite::scatter_packed`]).
fn scatter_packed(
    n: usize,
    s: usize,
    index: Vec<u32>,
    densities: &[Tensor],
    colours: &[Tensor],
    device: &candle_core::Device,
) -> Result<FieldOutput> {
    let (density, feature) = crate::kernels::composite::scatter_packed(
        index,
        (n, s),
        &concat_segments(densities, 1, device)?,
        &concat_segments(colours, 3, device)?,
    )?;
    Ok(FieldOutput { density, feature })
}

/// Segments `(M_k, width)` joined into one f32 `(ΣM_k, width)` tensor (empty: `(0, width)`).
fn concat_segments(parts: &[Tensor], width: usize, device: &candle_core::Device) -> Result<Tensor> {
    Ok(match parts.len() {
        0 => Tensor::zeros((0, width), DType::F32, device)?,
        _ => Tensor::cat(parts, 0)?.to_dtype(DType::F32)?,
    })
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use candle_core::Device;

    use super::*;
    use crate::field::nerf::{Nerf, NerfField, NerfParams};
    use crate::kernels::composite::composite;
    use crate::kernels::sample_points::sample_points;
    use crate::render::occupancy::{OccupancyGrid, OccupancyGridParams};
    use crate::render::renderer::{RenderOutput, VolumeRenderer};
    use crate::render::sampler::StratifiedSampler;

    /// A small NeRF whose density bias is `density_bias` (large values make rays terminate).
    fn model(density_bias: f32) -> Nerf {
        let cfg = NerfParams {
            n_harmonic_functions_xyz: 4,
            n_harmonic_functions_dir: 2,
            n_hidden_neurons_xyz: 32,
            n_hidden_neurons_dir: 16,
            n_layers_xyz: 3,
            append_xyz: vec![2],
        };
        // Seeded, so every run tests the same weights.
        let state = crate::field::nerf::NerfState::seeded(&cfg, 3, &Device::Cpu).unwrap();
        state.varmap.data().lock().unwrap()["density_layer.0.bias"]
            .set(&Tensor::new(&[density_bias], &Device::Cpu).unwrap())
            .unwrap();
        state.model
    }

    fn rays() -> Rays {
        let cam = crate::core::camera::surround_cameras(4.0, 3, glam::DVec3::Z, 2.0)[1];
        Rays::for_image(&cam, 9, 7, &Device::Cpu).unwrap()
    }

    fn render(
        renderer: VolumeRenderer,
        field: &NerfField,
        sampler: &StratifiedSampler,
    ) -> RenderOutput {
        renderer.render(field, sampler, &rays(), None).unwrap()
    }

    fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
        crate::core::compare::max_abs_difference(a, b).unwrap()
    }

    fn field(model: &Nerf, grid: Option<OccupancyGrid>) -> NerfField {
        NerfField {
            model: model.clone(),
            density_noise: 0.0,
            occupancy: grid.map(Arc::new),
        }
    }

    #[test]
    fn a_chunk_of_skipping_rays_draws_a_bounded_number_of_samples() {
        let m = model(0.0);
        let f = field(&m, None);
        let renderer = VolumeRenderer::new(1 << 20, false)
            .unwrap()
            .with_early_termination(1e-3)
            .unwrap();
        let per_segment = f.max_samples_per_chunk() / SEGMENT;
        for s in [16, 128, 4096, 16384] {
            let sampler = StratifiedSampler::new(s, 0.1, 6.0).unwrap();
            let rays = renderer.rays_per_chunk(&f, &sampler);
            assert!(
                rays * s <= crate::render::renderer::DRAWN_SAMPLES_PER_CHUNK,
                "S = {s}"
            );
            assert!(rays <= per_segment, "S = {s}");
            // Normal sizes keep the chunk the evaluated samples allow; only long rays shrink it.
            assert_eq!(rays == per_segment, s <= 4096, "S = {s}: {rays} rays");
        }
    }

    /// A 4³ grid over ±1 with cell `c` empty where `c % every == empty`.
    fn striped_grid(every: usize, empty: usize) -> OccupancyGrid {
        let config = OccupancyGridParams {
            resolution: 4,
            aabb: [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0],
            density_threshold: 1.0,
        };
        let mut grid = OccupancyGrid::new(&config).unwrap();
        for (c, o) in grid.occupied.iter_mut().enumerate() {
            *o = c % every != empty;
        }
        grid
    }

    #[test]
    fn packed_forward_equals_dense_forward() {
        let m = model(0.1);
        let points = Tensor::randn(0f32, 1.0, (4, 5, 3), &Device::Cpu).unwrap();
        let dirs = Tensor::randn(0f32, 1.0, (4, 3), &Device::Cpu).unwrap();
        let dense = m.forward(&points, &dirs, 0.0).unwrap();
        let index: Vec<u32> = vec![0, 3, 7, 8, 19];
        let idx = Tensor::new(index.as_slice(), &Device::Cpu).unwrap();
        let ray_index: Vec<u32> = index.iter().map(|k| k / 5).collect();
        let (density, colour) = m
            .forward_packed(
                &points
                    .reshape((20, 3))
                    .unwrap()
                    .index_select(&idx, 0)
                    .unwrap(),
                &Tensor::new(ray_index.as_slice(), &Device::Cpu).unwrap(),
                &dirs,
                0.0,
            )
            .unwrap();
        let pick =
            |t: &Tensor, c: usize| t.reshape((20, c)).unwrap().index_select(&idx, 0).unwrap();
        assert!(max_diff(&density, &pick(&dense.density, 1)) < 1e-6);
        assert!(max_diff(&colour, &pick(&dense.feature, 3)) < 1e-6);
    }

    #[test]
    fn all_occupied_grid_without_termination_is_dense_rendering() {
        let m = model(0.3);
        let sampler = StratifiedSampler::new(24, 2.0, 6.0).unwrap();
        // Large enough to hold every sample.
        let config = OccupancyGridParams {
            resolution: 64,
            aabb: [-10.0, -10.0, -10.0, 10.0, 10.0, 10.0],
            density_threshold: 1.0,
        };
        let grid = OccupancyGrid::new(&config).unwrap();
        let renderer = VolumeRenderer::new(1000, false).unwrap();
        let dense = render(renderer, &field(&m, None), &sampler);
        let skipped = render(renderer, &field(&m, Some(grid)), &sampler);
        assert_eq!(skipped.samples.evaluated, skipped.samples.total);
        assert!(max_diff(&dense.color, &skipped.color) < 1e-6);
        assert!(max_diff(&dense.depth, &skipped.depth) < 1e-5);
    }

    #[test]
    fn early_termination_error_is_bounded_by_its_threshold() {
        // Dense enough that most rays become opaque inside the aabb.
        let m = model(8.0);
        let sampler = StratifiedSampler::new(64, 2.0, 6.0).unwrap();
        let dense = render(
            VolumeRenderer::new(1000, false).unwrap(),
            &field(&m, None),
            &sampler,
        );
        for threshold in [1e-2, 1e-4] {
            let renderer = VolumeRenderer::new(1000, false)
                .unwrap()
                .with_early_termination(threshold)
                .unwrap();
            let out = render(renderer, &field(&m, None), &sampler);
            // Every ray turns opaque within its first 16 samples, so it stops by the end of
            // the fourth segment (4 + 4 + 8 + 16 of its 64 samples).
            assert!(
                out.samples.evaluated <= out.samples.total / 2,
                "{:?}",
                out.samples
            );
            // Dropped weights sum to at most the transmittance at termination.
            let colour_error = max_diff(&dense.color, &out.color);
            assert!(colour_error <= threshold as f32 * 1.001, "{colour_error}");
            let depth_error = max_diff(&dense.depth, &out.depth);
            assert!(
                depth_error <= 6.0 * threshold as f32 * 1.001,
                "{depth_error}"
            );
        }
    }

    #[test]
    fn empty_cells_render_as_zero_density() {
        let m = model(1.0);
        let sampler = StratifiedSampler::new(32, 2.0, 6.0).unwrap();
        let grid = striped_grid(3, 0);
        let renderer = VolumeRenderer::new(1000, false).unwrap();
        let out = render(renderer, &field(&m, Some(grid.clone())), &sampler);
        assert!(out.samples.evaluated < out.samples.total);
        // Independent recomputation: dense field, density zeroed outside occupied cells.
        let samples = sampler.sample(&rays(), None).unwrap();
        let dense = m.forward(&samples.points, &rays().directions, 0.0).unwrap();
        let points = samples
            .points
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let mask: Vec<f32> = points
            .chunks_exact(3)
            .map(|p| f32::from(u8::from(grid.is_occupied([p[0], p[1], p[2]]))))
            .collect();
        let mask = Tensor::from_vec(mask, samples.lengths.shape(), &Device::Cpu).unwrap();
        let density = dense.density.mul(&mask).unwrap();
        let Composited { color, depth, .. } =
            composite(&density, &dense.feature, &samples.lengths).unwrap();
        assert!(max_diff(&color, &out.color) < 1e-6);
        assert!(max_diff(&depth, &out.depth) < 1e-5);
    }

    #[test]
    fn marching_keeps_exactly_the_samples_in_occupied_cells() {
        use rand::{Rng, SeedableRng};
        // A 32³ grid over ±1.5 (4³ blocks): occupied cells scattered inside a ball, so most
        // blocks are empty and whole blocks are skipped.
        let config = OccupancyGridParams {
            resolution: 32,
            aabb: [-1.5, -1.5, -1.5, 1.5, 1.5, 1.5],
            density_threshold: 1.0,
        };
        let mut grid = OccupancyGrid::new(&config).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        for (c, o) in grid.occupied.iter_mut().enumerate() {
            let [x, y, z] = [c / 1024, (c / 32) % 32, c % 32].map(|v| v as f32 - 15.5);
            *o = x * x + y * y + z * z < 100.0 && rng.random::<f32>() < 0.3;
        }
        assert!(grid.empty_blocks().empty.iter().any(|e| *e));
        let f = field(&model(1.0).detached(), Some(grid.clone()));
        let cam = crate::core::camera::surround_cameras(4.0, 3, glam::DVec3::Z, 2.0)[1];
        let rays = Rays::for_image(&cam, 24, 20, &Device::Cpu).unwrap();
        let sampler = StratifiedSampler::new(96, 2.0, 6.0).unwrap();
        for jitter in [false, true] {
            let lengths = if jitter {
                sampler.compact_lengths(&rays, Some(&mut rng)).unwrap()
            } else {
                sampler.compact_lengths(&rays, None).unwrap()
            };
            let packed = evaluate_packed(&f, 0.0, &rays, &lengths).unwrap();
            // Every sample materialised and tested on its own.
            let dense_lengths = lengths.broadcast_as((rays.len(), 96, 1)).unwrap();
            let points = sample_points(&rays.origins, &rays.directions, &dense_lengths)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap();
            let expected: Vec<u32> = (0..points.len() / 3)
                .filter(|&k| {
                    grid.is_occupied([points[3 * k], points[3 * k + 1], points[3 * k + 2]])
                })
                .map(|k| k as u32)
                .collect();
            assert!(!expected.is_empty());
            let mut got = packed.index.clone();
            got.sort_unstable();
            assert_eq!(got, expected, "jitter {jitter}");
            assert!(
                packed.counts.examined < packed.counts.total / 2,
                "{:?}",
                packed.counts
            );
        }
    }

    #[test]
    fn packed_compositing_equals_the_dense_scatter_bit_for_bit() {
        let m = model(2.0);
        let sampler = StratifiedSampler::new(48, 2.0, 6.0).unwrap();
        let grid = striped_grid(5, 0);
        let f = field(&m.detached(), Some(grid));
        let samples = sampler.sample(&rays(), None).unwrap();
        for termination in [0.0, 1e-2] {
            let packed = evaluate_packed(&f, termination, &rays(), &samples.lengths).unwrap();
            assert!(!packed.tracks_gradient());
            let (direct, dense) = composited_packed_and_dense(packed, &samples.lengths);
            for (what, a, b) in [
                ("colour", &direct.color, &dense.color),
                ("depth", &direct.depth, &dense.depth),
                ("opacity", &direct.opacity, &dense.opacity),
            ] {
                assert_eq!(max_diff(a, b), 0.0, "{what}, termination {termination}");
            }
        }
    }

    /// The packed values composited straight ([`PackedSamples::composite`]) and after
    /// scattering them into dense tensors ([`composite`]).
    fn composited_packed_and_dense(
        packed: PackedSamples,
        lengths: &Tensor,
    ) -> (Composited, Composited) {
        let direct = packed.composite(lengths).unwrap();
        let dense = packed.scatter(&Device::Cpu).unwrap();
        let dense = composite(&dense.density, &dense.feature, lengths).unwrap();
        (direct, dense)
    }

    #[test]
    fn packed_compositing_gradients_equal_the_dense_paths() {
        let state = {
            let cfg = NerfParams {
                n_harmonic_functions_xyz: 3,
                n_harmonic_functions_dir: 2,
                n_hidden_neurons_xyz: 16,
                n_hidden_neurons_dir: 8,
                n_layers_xyz: 2,
                append_xyz: vec![1],
            };
            crate::field::nerf::NerfState::seeded(&cfg, 5, &Device::Cpu).unwrap()
        };
        let sampler = StratifiedSampler::new(32, 2.0, 6.0).unwrap();
        let grid = striped_grid(4, 1);
        let f = field(&state.model, Some(grid));
        let samples = sampler.sample(&rays(), None).unwrap();
        let packed = evaluate_packed(&f, 1e-3, &rays(), &samples.lengths).unwrap();
        assert!(packed.tracks_gradient());
        let (direct, dense) = composited_packed_and_dense(packed, &samples.lengths);
        let weight = Tensor::randn(0f32, 1.0, direct.color.shape(), &Device::Cpu).unwrap();
        let loss = |out: &Composited| {
            let l = (out.color.mul(&weight).unwrap().sum_all().unwrap()
                + out.depth.sum_all().unwrap().affine(0.1, 0.0).unwrap())
            .unwrap();
            (l + out.opacity.sum_all().unwrap())
                .unwrap()
                .backward()
                .unwrap()
        };
        let (ga, gb) = (loss(&direct), loss(&dense));
        for (name, var) in crate::field::trainable::named_vars(&state.varmap) {
            let (a, b) = (ga.get(&var).unwrap(), gb.get(&var).unwrap());
            crate::core::compare::assert_close(a, b, 1e-5, &name);
        }
    }
}
