//! One ray of the fused SDF render's training pass, in structure-of-arrays form: the replay
//! (every sample's transparency, colour and partial derivatives, then the running
//! transmittance) and the reverse pass (the compositing gradients turned into gradients of
//! the packed parameters). The maths is [`SdfVolume`]'s; this module only lays it out so
//! that the per-sample work runs in blocks of [`BLOCK`] samples the compiler vectorises,
//! with the shape chosen once per ray rather than per sample. Each public function runs a
//! copy compiled for AVX2 where the CPU has it (checked at run time), else the baseline
//! (SSE2) one.

// Index loops walk several per-sample arrays in step; iterator chains would hide that (and
// the fixed-size ones are what the compiler vectorises).
#![allow(clippy::needless_range_loop)]

use crate::cpu_dispatch::dispatched;
use crate::sdf_point::{
    box_distance_with_gradient, colour_at, colour_factors, packed_layout,
    sphere_distance_with_gradient, transparency_from_distance, transparency_parts, PackedLayout,
};
use nerf_core::sdf::{Sdf, SdfVolume};
use nerf_core::volume::spacing;

/// Samples computed together before the running transmittance is checked.
pub(crate) const BLOCK: usize = 16;

/// Per-sample values of one ray, one array per quantity (index = sample).
#[derive(Debug, Default)]
pub(crate) struct RayScratch {
    /// Depth `t_i`.
    t: Vec<f32>,
    /// `e^{−τ_i}` after the replay's first loop, then the weight `w_i`.
    weight: Vec<f32>,
    /// Transmittance after the sample, `T_{i+1}`.
    after: Vec<f32>,
    /// Colour scale per channel (`sdf_point::colour_factors`).
    scale: [Vec<f32>; 3],
    /// `∂scale_k/∂c_k` per channel.
    d_scale: [Vec<f32>; 3],
    /// `∂τ/∂center`.
    d_center: [Vec<f32>; 3],
    /// `∂τ/∂shape`.
    d_shape: [Vec<f32>; 3],
    /// `∂τ/∂α`.
    d_alpha: Vec<f32>,
    /// `∂τ/∂β`.
    d_beta: Vec<f32>,
    /// `g_i`, then `∂L/∂τ_i`, in the reverse pass.
    g: Vec<f32>,
}

impl RayScratch {
    /// Scratch for rays of `s` samples.
    pub(crate) fn new(s: usize) -> Self {
        let v = || vec![0f32; s];
        Self {
            t: v(),
            weight: v(),
            after: v(),
            scale: [v(), v(), v()],
            d_scale: [v(), v(), v()],
            d_center: [v(), v(), v()],
            d_shape: [v(), v(), v()],
            d_alpha: v(),
            d_beta: v(),
            g: v(),
        }
    }
}

/// One block's per-sample values (fixed-size arrays, so that the loop over them vectorises).
#[derive(Default)]
struct Block {
    clear: [f32; BLOCK],
    scale: [[f32; BLOCK]; 3],
    d_scale: [[f32; BLOCK]; 3],
    d_center: [[f32; BLOCK]; 3],
    d_shape: [[f32; BLOCK]; 3],
    d_alpha: [f32; BLOCK],
    d_beta: [f32; BLOCK],
}

/// The blocks `start..end` of [`BLOCK`] samples (the last one shorter) of `s` samples, in order.
#[inline(always)]
fn blocks(s: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..s)
        .step_by(BLOCK)
        .map(move |start| (start, (start + BLOCK).min(s)))
}

/// Samples `start..end` (at most [`BLOCK`]) of a block, padded with zeros: their lengths, and
/// 1 for each sample with a spacing, 0 for one without (zero spacing: zero optical depth
/// whatever the density, see [`nerf_core::volume`]).
#[inline(always)]
fn block_samples(lengths: &[f32], (start, end): (usize, usize)) -> ([f32; BLOCK], [f32; BLOCK]) {
    let m = end - start;
    let mut t = [0f32; BLOCK];
    let mut live = [0f32; BLOCK];
    t[..m].copy_from_slice(&lengths[start..end]);
    for j in 0..m {
        live[j] = if spacing(lengths, start + j) == 0.0 {
            0.0
        } else {
            1.0
        };
    }
    (t, live)
}

/// The point at length `t` along `ray` = `[origin, direction]`: `o + t·d`.
#[inline(always)]
fn point_at(ray: &[f32], t: f32) -> [f32; 3] {
    [
        ray[0] + t * ray[3],
        ray[1] + t * ray[4],
        ray[2] + t * ray[5],
    ]
}

/// Fills samples `start..end` (at most [`BLOCK`]) of the scratch (everything but the
/// weights' running product) for the ray `ray` = `[origin, direction]`; `distance` is the
/// shape's signed distance with its derivatives.
#[inline(always)]
fn fill<D>(
    volume: &SdfVolume,
    distance: D,
    ray: &[f32],
    lengths: &[f32],
    (start, end): (usize, usize),
    sc: &mut RayScratch,
) where
    D: Fn([f32; 3]) -> (f32, [f32; 3], [f32; 3]),
{
    let m = end - start;
    let (t, live) = block_samples(lengths, (start, end));
    let mut b = Block::default();
    for j in 0..BLOCK {
        let point = point_at(ray, t[j]);
        let (clear, d) = transparency_from_distance(volume, distance(point));
        let (scale, d_scale) = colour_factors(volume, point);
        b.clear[j] = 1.0 - live[j] * (1.0 - clear);
        for k in 0..3 {
            b.scale[k][j] = scale[k];
            b.d_scale[k][j] = d_scale[k];
            b.d_center[k][j] = live[j] * d.center[k];
            b.d_shape[k][j] = live[j] * d.shape[k];
        }
        b.d_alpha[j] = live[j] * d.alpha;
        b.d_beta[j] = live[j] * d.beta;
    }
    let r = start..end;
    sc.t[r.clone()].copy_from_slice(&t[..m]);
    sc.weight[r.clone()].copy_from_slice(&b.clear[..m]);
    for k in 0..3 {
        sc.scale[k][r.clone()].copy_from_slice(&b.scale[k][..m]);
        sc.d_scale[k][r.clone()].copy_from_slice(&b.d_scale[k][..m]);
        sc.d_center[k][r.clone()].copy_from_slice(&b.d_center[k][..m]);
        sc.d_shape[k][r.clone()].copy_from_slice(&b.d_shape[k][..m]);
    }
    sc.d_alpha[r.clone()].copy_from_slice(&b.d_alpha[..m]);
    sc.d_beta[r].copy_from_slice(&b.d_beta[..m]);
}

dispatched! {
    /// One ray's `[r, g, b, depth, opacity]` ([`crate::sdf_render`]'s forward pass):
    /// blocks of [`BLOCK`] samples' transparency `e^{−τ} = 1 − density` and colour, composited,
    /// stopping after the block in which the transmittance reaches 0. (AVX2 takes 8 samples
    /// per vector instead of SSE2's 4.)
    pub(crate) fn forward(volume: &SdfVolume, ray: &[f32], lengths: &[f32]) -> [f32; 5]
        = forward_portable for ["avx2"];
}

/// [`forward`] for any CPU.
#[inline(always)]
fn forward_portable(volume: &SdfVolume, ray: &[f32], lengths: &[f32]) -> [f32; 5] {
    match volume.sdf {
        Sdf::Box {
            center,
            side_lengths,
        } => forward_with(
            volume,
            |p| box_distance(&center, &side_lengths, p),
            ray,
            lengths,
        ),
        Sdf::Sphere { .. } => forward_with(volume, |p| volume.sdf.distance(p), ray, lengths),
    }
}

/// The box's signed distance ([`Sdf::distance`] of a box), for a loop that picked the shape.
#[inline(always)]
fn box_distance(center: &[f32; 3], side_lengths: &[f32; 3], p: [f32; 3]) -> f32 {
    Sdf::Box {
        center: *center,
        side_lengths: *side_lengths,
    }
    .distance(p)
}

/// [`forward`] with the shape's signed distance `distance`.
#[inline(always)]
fn forward_with<D: Fn([f32; 3]) -> f32>(
    volume: &SdfVolume,
    distance: D,
    ray: &[f32],
    lengths: &[f32],
) -> [f32; 5] {
    let mut out = [0f32; 5];
    let mut transmittance = 1f32;
    for (start, end) in blocks(lengths.len()) {
        let m = end - start;
        let (t, live) = block_samples(lengths, (start, end));
        let mut clear = [0f32; BLOCK];
        let mut colour = [[0f32; BLOCK]; 3];
        for j in 0..BLOCK {
            let p = point_at(ray, t[j]);
            let (c, _, _) = transparency_parts(volume, distance(p));
            clear[j] = 1.0 - live[j] * (1.0 - c);
            let rgb = colour_at(volume, p);
            for k in 0..3 {
                colour[k][j] = rgb[k];
            }
        }
        for j in 0..m {
            let w = transmittance * (1.0 - clear[j]);
            transmittance *= clear[j];
            for k in 0..3 {
                out[k] += w * colour[k][j];
            }
            out[3] += w * t[j];
            out[4] += w;
        }
        if transmittance == 0.0 {
            break;
        }
    }
    out
}

dispatched! {
    /// Replays one ray `[origin, direction]` at `lengths` into `sc`, up to the block in which
    /// its transmittance reaches 0; returns how many samples that is and the ray's `[r, g, b,
    /// depth, opacity]`. The weights use `e^{−τ} = 1 − density`
    /// (`sdf_point::transparency_from_distance`).
    pub(crate) fn replay(
        volume: &SdfVolume,
        ray: &[f32],
        lengths: &[f32],
        sc: &mut RayScratch,
    ) -> (usize, [f32; 5]) = replay_portable for ["avx2"];
}

/// [`replay`] for any CPU.
#[inline(always)]
fn replay_portable(
    volume: &SdfVolume,
    ray: &[f32],
    lengths: &[f32],
    sc: &mut RayScratch,
) -> (usize, [f32; 5]) {
    let s = lengths.len();
    let mut out = [0f32; 5];
    let mut transmittance = 1f32;
    for (start, end) in blocks(s) {
        match volume.sdf {
            Sdf::Box {
                center,
                side_lengths,
            } => fill(
                volume,
                |p| box_distance_with_gradient(&center, &side_lengths, p),
                ray,
                lengths,
                (start, end),
                sc,
            ),
            Sdf::Sphere { center, radius } => fill(
                volume,
                |p| sphere_distance_with_gradient(&center, radius, p),
                ray,
                lengths,
                (start, end),
                sc,
            ),
        }
        for i in start..end {
            let a = sc.weight[i];
            let w = transmittance * (1.0 - a);
            transmittance *= a;
            sc.weight[i] = w;
            sc.after[i] = transmittance;
            for c in 0..3 {
                out[c] += w * sc.scale[c][i] * volume.feature[c];
            }
            out[3] += w * sc.t[i];
            out[4] += w;
        }
        if transmittance == 0.0 {
            // Every later weight is exactly 0: the rest of the ray changes nothing.
            return (end, out);
        }
    }
    (s, out)
}

dispatched! {
    /// Adds the parameter gradients of the first `n` replayed samples in `sc` to `acc` (packed
    /// layout) for the output gradient `grad` (`[G_r, G_g, G_b, G_depth, G_opacity]`):
    /// `Σ_i ∂L/∂τ_i ∂τ_i/∂θ` with `∂L/∂τ_i = T_{i+1} g_i − Σ_{j>i} w_j g_j`, `g_i = Σ_c G_c
    /// c_ic + G_depth t_i + G_opacity`, and the colour's `Σ_i w_i G_c ∂c_ic/∂θ`.
    pub(crate) fn reverse(
        volume: &SdfVolume,
        sc: &mut RayScratch,
        n: usize,
        grad: &[f32],
        acc: &mut [f64],
    ) = reverse_portable for ["avx2"];
}

/// [`reverse`] for any CPU.
#[inline(always)]
fn reverse_portable(
    volume: &SdfVolume,
    sc: &mut RayScratch,
    n: usize,
    grad: &[f32],
    acc: &mut [f64],
) {
    let f = volume.feature;
    let gf = [grad[0] * f[0], grad[1] * f[1], grad[2] * f[2]];
    let (s0, s1, s2) = (&sc.scale[0][..n], &sc.scale[1][..n], &sc.scale[2][..n]);
    for ((((g, t), a), b), c) in sc.g[..n].iter_mut().zip(&sc.t[..n]).zip(s0).zip(s1).zip(s2) {
        *g = gf[0] * a + gf[1] * b + gf[2] * c + grad[3] * t + grad[4];
    }
    // ∂L/∂τ_i, walking back with the suffix sum Σ_{j>i} w_j g_j.
    let mut suffix = 0f32;
    for ((g, after), w) in sc.g[..n]
        .iter_mut()
        .zip(&sc.after[..n])
        .zip(&sc.weight[..n])
        .rev()
    {
        let gi = *g;
        *g = after * gi - suffix;
        suffix += w * gi;
    }
    let (g, w) = (&sc.g[..n], &sc.weight[..n]);
    let layout: PackedLayout = packed_layout(volume);
    for k in 0..3 {
        let colour_center = dot(w, &sc.d_scale[k][..n]) * gf[k] as f64;
        acc[k] += dot(g, &sc.d_center[k][..n]) + colour_center;
        acc[layout.feature() + k] += dot(w, &sc.scale[k][..n]) * grad[k] as f64;
    }
    for k in 0..layout.shape_len {
        acc[PackedLayout::SHAPE + k] += dot(g, &sc.d_shape[k][..n]);
    }
    acc[layout.alpha()] += dot(g, &sc.d_alpha[..n]);
    acc[layout.beta()] += dot(g, &sc.d_beta[..n]);
}

#[inline(always)]
/// `Σ a_i b_i` of two equally long slices, summed in 8 float32 lanes (so that it
/// vectorises; a ray's few samples lose nothing that matters), returned as float64.
fn dot(a: &[f32], b: &[f32]) -> f64 {
    let mut lanes = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            lanes[l] += x[l] * y[l];
        }
    }
    (lanes.iter().sum::<f32>() + tail) as f64
}
