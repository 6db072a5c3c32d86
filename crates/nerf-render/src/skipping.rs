//! Evaluating a field only at the samples that can contribute: empty-space skipping with an
//! [`crate::occupancy::OccupancyGrid`] and early ray termination.
//!
//! The samples of a ray that lie in occupied cells are visited in segments, front to back:
//! `segment_sizes` of them per ray (4, 4, 8, then 16 at a time), so that most rays, which
//! end within a few samples of the surface, cost a few field calls. In each segment the field
//! is evaluated at the next occupied samples of still-live rays, as one packed batch. After a
//! segment, a ray whose transmittance `exp(−Σ τ)` has fallen below the early-termination
//! threshold is dropped. The packed densities and colours are then composited where they are
//! ([`nerf_kernels::composite::composite_packed`], forward and backward over the evaluated
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

use crate::field::{packed_evaluation, Field, FieldOutput};
use crate::occupancy::{EmptyBlocks, OccupancyGrid, RayFaces};
use nerf_core::rays::Rays;
use nerf_core::volume::{clamped_optical_depth, spacing};
use nerf_kernels::composite::{composite_packed, Composited, PackedDensities, PackedValues};
use nerf_kernels::distortion_loss::distortion_loss_packed;
use nerf_kernels::distortion_loss::RaySpacing;

/// The most occupied samples per ray evaluated between early-termination checks.
pub const SEGMENT: usize = 16;

/// How many occupied samples per ray the `k`-th segment takes: 4, 4, 8, then [`SEGMENT`].
pub(crate) fn segment_sizes(k: usize) -> usize {
    match k {
        0 | 1 => 4,
        2 => 8,
        _ => SEGMENT,
    }
}

/// The most samples per ray evaluated in one batch: [`SEGMENT`] with early termination, all
/// of them without (there is nothing to check between segments).
pub(crate) fn segment_length(n_pts_per_ray: usize, early_termination: f64) -> usize {
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
    pub(crate) fn dense(total: usize) -> Self {
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
/// indices of the evaluated samples and the field's values there, by segment
/// ([`march_packed`]).
///
/// `rays`: N rays; `lengths`: each ray's sample depths `(N, S, 1)`, increasing, or `(1, S, 1)`
/// depths shared by all rays.
pub fn evaluate_packed(
    field: &dyn Field,
    early_termination: f64,
    rays: &Rays,
    lengths: &Tensor,
) -> Result<PackedSamples> {
    let device = lengths.device();
    let s = lengths.dim(1)?;
    // Rays whose origins or directions are being trained (camera refinement) get their
    // evaluated points as tensor ops, so the gradient reaches them.
    let rays_tracked = rays.origins.track_op() || rays.directions.track_op();
    let mut densities = Vec::new();
    let mut colours = Vec::new();
    let (index, counts) = march_packed(
        field.occupancy(),
        early_termination,
        rays,
        lengths,
        |segment: MarchedSegment| {
            let m = segment.index.len();
            let ray_index = Tensor::from_vec(segment.ray_index, m, device)?;
            let points = match rays_tracked {
                true => tracked_points(rays, &ray_index, segment.index, segment.lengths, s)?,
                false => Tensor::from_vec(segment.points, (m, 3), device)?,
            };
            let (density, colour) =
                packed_evaluation(field, &points, &ray_index, &rays.directions)?;
            let values = match early_termination > 0.0 {
                true => density.flatten_all()?.to_vec1::<f32>()?,
                false => Vec::new(),
            };
            densities.push(density);
            colours.push(colour);
            Ok(values)
        },
    )?;
    Ok(PackedSamples {
        rays: rays.len(),
        per_ray: s,
        index,
        densities,
        colours,
        counts,
    })
}

/// One segment's samples, as [`march_packed`] hands them to its evaluator: their flat sample
/// indices `ray · S + i`, points `(M, 3)` and rays `(M)`, and the depths they were drawn from
/// (ray `r`'s `S` depths at `r · stride`).
pub struct MarchedSegment<'a> {
    /// Flat sample index `ray · S + i` of each sample.
    pub index: &'a [u32],
    /// The samples' points, 3 values each.
    pub points: Vec<f32>,
    /// Each sample's ray.
    pub ray_index: Vec<u32>,
    /// The sample depths and the row stride between rays (0: shared by all rays).
    pub lengths: (&'a [f32], usize),
}

/// Marches `rays` over the samples that can contribute (see the module) in segments, front to
/// back, and hands each segment's samples to `evaluate`, which returns their densities `(M)`
/// (read only with early termination: an empty vector serves without). Returns the flat
/// indices of every evaluated sample, in evaluation order, and the sample counts.
///
/// The samples are marched, not materialised: each ray's points `o + t·d` are formed only
/// where they are tested, from the first sample that can lie in `grid`'s bounding box
/// (`OccupancyGrid::crossing`) and only as far as the ray is still live, so a ray that
/// misses the box costs nothing and one that ends at a surface is not tested behind it.
///
/// `rays`: N rays; `lengths`: each ray's sample depths `(N, S, 1)`, increasing, or `(1, S, 1)`
/// depths shared by all rays.
pub fn march_packed(
    grid: Option<&OccupancyGrid>,
    early_termination: f64,
    rays: &Rays,
    lengths: &Tensor,
    mut evaluate: impl FnMut(MarchedSegment) -> Result<Vec<f32>>,
) -> Result<(Vec<u32>, SampleCounts)> {
    let (rows, s, _) = lengths.dims3()?;
    let n = rays.len();
    anyhow::ensure!(
        rows == n || rows == 1,
        "sample lengths have {rows} rows for {n} rays"
    );
    // Ray `ray`'s depths start at `ray · stride` (0 when shared).
    let stride = if rows == 1 { 0 } else { s };
    let lengths = lengths
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let grid = grid.map(|grid| MarchGrid {
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
    // Samples tested by the marches of rays no longer marched.
    let mut examined = 0;
    for k in 0.. {
        let size = if early_termination > 0.0 {
            segment_sizes(k)
        } else {
            s
        };
        let (index, points, ray_index) =
            march_segment(&mut marches, grid, &lengths, stride, s, size);
        if index.is_empty() {
            break;
        }
        let values = evaluate(MarchedSegment {
            index: &index,
            points,
            ray_index,
            lengths: (&lengths, stride),
        })?;
        if depth_limit.is_finite() {
            anyhow::ensure!(
                values.len() == index.len(),
                "{} densities for {} samples",
                values.len(),
                index.len()
            );
            for (&k, &sigma) in index.iter().zip(&values) {
                let (ray, i) = (k as usize / s, k as usize % s);
                let delta = spacing(&lengths[ray * stride..ray * stride + s], i);
                ray_depth[ray] += clamped_optical_depth(sigma, delta);
            }
        }
        all_index.extend(index);
        // Only rays that may still have samples are marched again (in ray order, so the
        // samples stay grouped by ray): a finished march need not be visited.
        marches.retain(|m| {
            let keep = !m.finished && ray_depth[m.ray as usize] < depth_limit;
            if !keep {
                examined += m.examined;
            }
            keep
        });
    }
    counts.evaluated = all_index.len();
    counts.examined = examined + marches.iter().map(|m| m.examined).sum::<usize>();
    Ok((all_index, counts))
}

/// The evaluated points `(M, 3)` as tensor ops on the rays, `o[r] + t·d[r]` for each sample
/// of flat index `ray · S + i` in `index` on ray `r` of `ray_index` `(M,)` (a gather and a
/// broadcast), so that autograd carries their gradient to `rays`' origins and directions.
/// `lengths`: ray `r`'s `S` depths start at `r · stride`. The values are the marched points'.
fn tracked_points(
    rays: &Rays,
    ray_index: &Tensor,
    index: &[u32],
    lengths: (&[f32], usize),
    s: usize,
) -> Result<Tensor> {
    let (lengths, stride) = lengths;
    let depths: Vec<f32> = index
        .iter()
        .map(|&k| {
            let (ray, i) = (k as usize / s, k as usize % s);
            lengths[ray * stride + i]
        })
        .collect();
    let depths = Tensor::from_vec(depths, (index.len(), 1), ray_index.device())?;
    let gather = |t: &Tensor| {
        t.to_dtype(DType::F32)?
            .contiguous()?
            .index_select(ray_index, 0)
    };
    let (origins, directions) = (gather(&rays.origins)?, gather(&rays.directions)?);
    Ok(origins.add(&directions.broadcast_mul(&depths)?)?)
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
        .into_par_iter()
        .map(|ray| {
            let t = &lengths[ray * stride..ray * stride + s];
            let (o, d) = (&origins[3 * ray..], &directions[3 * ray..]);
            RayMarch::new(grid, ray, [o[0], o[1], o[2]], [d[0], d[1], d[2]], t)
        })
        .collect())
}

/// The next `size` occupied samples of the rays of `marches` (in ray order), marched in
/// parallel blocks of rays and joined in order: flat sample indices `ray · S + i`, points (3
/// values each) and ray indices. A march that runs out of samples is marked finished.
/// `lengths`: ray `r`'s `S` depths start at `r · stride`.
fn march_segment(
    marches: &mut [RayMarch],
    grid: Option<&MarchGrid>,
    lengths: &[f32],
    stride: usize,
    s: usize,
    size: usize,
) -> (Vec<u32>, Vec<f32>, Vec<u32>) {
    let parts: Vec<Segment> = marches
        .par_chunks_mut(MARCH_BLOCK)
        .map(|block| {
            let mut part = Segment::default();
            for march in block.iter_mut() {
                let ray = march.ray as usize;
                let t = &lengths[ray * stride..ray * stride + s];
                for _ in 0..size {
                    let Some((i, p)) = march.next_occupied(grid, t) else {
                        march.finished = true;
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
/// samples that can lie in the grid's box, how many were tested, and the depth before which
/// later samples are known to share the occupied cell of the last tested one.
struct RayMarch {
    /// The ray's index in the batch.
    ray: u32,
    /// Whether the walk has passed its last sample.
    finished: bool,
    origin: [f32; 3],
    direction: [f32; 3],
    faces: Option<RayFaces>,
    next: usize,
    end: usize,
    examined: usize,
    /// Samples deeper than the last tested one and shallower than this lie in its cell, an
    /// occupied one ([`RayFaces::exit`]); −∞ until one is found.
    occupied_end: f64,
}

impl RayMarch {
    /// The walk over depths `t` (increasing) of the ray `origin + t·direction`: every sample
    /// without a grid, else those that can lie in its box, one sample of margin either side
    /// for rounding (the exact test is [`OccupancyGrid::is_occupied`] at each point).
    fn new(
        grid: Option<&MarchGrid>,
        ray: usize,
        origin: [f32; 3],
        direction: [f32; 3],
        t: &[f32],
    ) -> Self {
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
            ray: ray as u32,
            finished: false,
            origin,
            direction,
            faces: grid.and_then(|g| g.grid.ray_faces(origin, direction)),
            next,
            end,
            examined: 0,
            occupied_end: f64::NEG_INFINITY,
        }
    }

    /// The point `o + t·d` (the same f32 arithmetic as [`nerf_kernels::sample_points`]).
    #[inline]
    fn point(&self, t: f32) -> [f32; 3] {
        std::array::from_fn(|k| self.origin[k] + t * self.direction[k])
    }

    /// With a contraction, where [`RayFaces`] do not apply: the depth to pass over to when the
    /// cell at coordinates `cell` lies in an empty block inside the unit cube
    /// ([`OccupancyGrid::empty_block_crossing`]), keeping [`BLOCK_MARGIN`] from its faces; −∞
    /// (nothing passed over) otherwise, or when the next sample is within the margin of the
    /// block's entry.
    fn contracted_block_end(&self, g: &MarchGrid, cell: [usize; 3], t: &[f32]) -> f64 {
        let crossing = g
            .grid
            .empty_block_crossing(&g.blocks, cell, self.origin, self.direction);
        match crossing {
            Some((enter, exit))
                if self.next < self.end && f64::from(t[self.next]) > enter + BLOCK_MARGIN =>
            {
                exit - BLOCK_MARGIN
            }
            _ => f64::NEG_INFINITY,
        }
    }

    /// The next sample in an occupied cell (all samples without a grid): its index along the
    /// ray and its point, or `None` when the ray has no more. Marching goes cell by cell: a
    /// sample is looked up in the grid only when it is not known to share the cell of the
    /// last one looked up ([`RayFaces::exit`]); an empty cell, or its block when that is empty
    /// too, is passed over without a lookup (with a contraction, only empty blocks inside the
    /// unit cube, keeping [`BLOCK_MARGIN`] from their faces). The result is exactly the
    /// per-sample test's.
    fn next_occupied(&mut self, grid: Option<&MarchGrid>, t: &[f32]) -> Option<(usize, [f32; 3])> {
        while self.next < self.end {
            let i = self.next;
            self.next += 1;
            if f64::from(t[i]) < self.occupied_end {
                return Some((i, self.point(t[i])));
            }
            self.examined += 1;
            let p = self.point(t[i]);
            let Some(g) = grid else {
                return Some((i, p));
            };
            // [`OccupancyGrid::is_occupied`], keeping the cell for the skips.
            let Some(cell) = g.grid.cell_coordinates(p) else {
                continue;
            };
            if g.grid.occupied[g.grid.cell_index(cell)] {
                if let Some(faces) = &self.faces {
                    self.occupied_end = faces.exit(cell);
                }
                return Some((i, p));
            }
            // Pass over the rest of the empty cell, and of its block when that is empty too.
            let skip_to = match &self.faces {
                Some(faces) if g.blocks.holds_empty(cell) => faces.block_exit(cell),
                Some(faces) => faces.exit(cell),
                None => self.contracted_block_end(g, cell, t),
            };
            while self.next < self.end && f64::from(t[self.next]) < skip_to {
                self.next += 1;
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

    /// Each ray's distortion loss `(N, 1)` from the packed densities
    /// ([`distortion_loss_packed`]; differentiable), given `lengths` as
    /// [`PackedSamples::composite`] takes them, measured in `spacing`.
    pub(crate) fn distortion(&self, lengths: &Tensor, spacing: RaySpacing) -> Result<Tensor> {
        let samples = PackedDensities {
            index: self.index.clone(),
            n_rays: self.rays,
            density: concat_segments(&self.densities, 1, lengths.device())?,
        };
        distortion_loss_packed(samples, lengths, spacing)
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
/// tensors, zeros elsewhere ([`nerf_kernels::composite::scatter_packed`]).
fn scatter_packed(
    n: usize,
    s: usize,
    index: Vec<u32>,
    densities: &[Tensor],
    colours: &[Tensor],
    device: &candle_core::Device,
) -> Result<FieldOutput> {
    let (density, feature) = nerf_kernels::composite::scatter_packed(
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
