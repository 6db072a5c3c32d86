//! Fused volume compositing on the CPU: weights and their weighted sums in one pass per ray,
//! with a hand-written backward pass so training uses the same code path as rendering.
//!
//! Inputs: density σ `(N, S, 1)`, sample lengths t `(N, S, 1)`, features v `(N, S, C)`; σ and
//! v may be strided views (no copies are made). Spacings are `Δ_i = t_{i+1} − t_i`, with
//! `nerf_core::volume::LAST_DELTA` for the last sample. Output `(N, C + 2)`: colour `Σ_i w_i v_ic`, depth
//! `Σ_i w_i t_i`, opacity `Σ_i w_i`, where `τ_i = clamp(σ_i Δ_i, 0, MAX_OPTICAL_DEPTH)`,
//! `T_i = Π_{j<i} e^{−τ_j}`, `w_i = T_i (1 − e^{−τ_i})` — the maths of
//! [`nerf_core::volume::weights`].
//!
//! Backward, with `g_i = Σ_c G_c v_ic + G_depth t_i + G_opacity` for the output gradient G:
//! `∂L/∂v_ic = w_i G_c` and `∂L/∂τ_i = T_{i+1} g_i − Σ_{j>i} w_j g_j`, so
//! `∂L/∂σ_i = Δ_i ∂L/∂τ_i` for `0 ≤ σΔ < MAX_OPTICAL_DEPTH` and 0 above, where the clamp holds
//! the optical depth constant. Lengths get no gradient.

// Index loops walk several per-ray arrays in step; iterator chains would hide that.
#![allow(clippy::needless_range_loop)]

use anyhow::Result;
use candle_core::{DType, Shape, Tensor};
use rayon::prelude::*;

use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use crate::storage::host_values;

use crate::use_fused;
use nerf_core::volume::{
    aggregate, clamped_optical_depth, deltas, ray_weights, spacing, weights, MAX_OPTICAL_DEPTH,
};

/// Rays per parallel work item.
const RAYS_PER_TASK: usize = 256;

/// What compositing N rays' samples gives.
#[derive(Debug, Clone)]
pub struct Composited {
    /// `(N, C)` colour: the weighted sum of the samples' features.
    pub color: Tensor,
    /// `(N, 1)` expected depth `Σ w t`.
    pub depth: Tensor,
    /// `(N, 1)` opacity `Σ w`.
    pub opacity: Tensor,
}

impl Composited {
    /// A fused op's `(N, C + 2)` output `[colour, depth, opacity]`, split.
    pub(crate) fn from_columns(out: &Tensor, c: usize) -> Result<Self> {
        Ok(Composited {
            color: out.narrow(1, 0, c)?,
            depth: out.narrow(1, c, 1)?,
            opacity: out.narrow(1, c + 1, 1)?,
        })
    }
}

/// The evaluated samples of a skipping render, packed: `index` holds the flat sample index
/// `ray · S + i` of each (any order, no repeats) over `n_rays` rays, `density` `(M, 1)` and
/// `feature` `(M, C)` the field's values there.
#[derive(Debug, Clone)]
pub struct PackedValues {
    /// Flat sample index `ray · S + i` of each value.
    pub index: Vec<u32>,
    /// Rays N.
    pub n_rays: usize,
    /// Densities `(M, 1)`.
    pub density: Tensor,
    /// Features `(M, C)`.
    pub feature: Tensor,
}

/// The densities alone of a skipping render's packed samples, as [`PackedValues`] lists them:
/// what the packed distortion loss reads.
#[derive(Debug, Clone)]
pub struct PackedDensities {
    /// Flat sample index `ray · S + i` of each density.
    pub index: Vec<u32>,
    /// Rays N.
    pub n_rays: usize,
    /// Densities `(M, 1)`.
    pub density: Tensor,
}

/// Colour, depth and opacity of each ray from its samples: the weights and their weighted
/// sums, with spacings derived from the lengths ([`nerf_core::volume::deltas`]). The fused
/// `Composite` kernel (forward and backward) where [`use_fused`] allows, else
/// `composite_tensor_ops`.
///
/// `density`, `lengths`: `(N, S, 1)`; `feature`: `(N, S, C)`. Returns colour `(N, C)`, depth
/// `(N, 1)` and opacity `(N, 1)`.
pub fn composite(density: &Tensor, feature: &Tensor, lengths: &Tensor) -> Result<Composited> {
    if !use_fused(density) {
        return composite_tensor_ops(density, feature, lengths);
    }
    let c = feature.dim(2)?;
    // σ and the features are read through their strides, so a field's output is not copied.
    Composited::from_columns(&density.apply_op3(lengths, feature, Fused(Composite))?, c)
}

/// The packed samples of a skipping render grouped by ray: `index` holds the flat sample
/// index `ray · S + i` of each evaluated sample (any order, no repeats).
pub struct PackedRays {
    pub(crate) n: usize,
    s: usize,
    pub(crate) index: Vec<u32>,
    /// Entries of ray `r`: `order[start[r]..start[r + 1]]`, in sample order.
    start: Vec<usize>,
    order: Vec<u32>,
    /// Every sample's length, `N·S`, or one row of `S` shared by all rays.
    lengths: Vec<f32>,
}

impl PackedRays {
    /// The samples `index` of `n_rays` rays grouped by ray, given `lengths` `(N, S, 1)`, or
    /// `(1, S, 1)` shared by all rays (read as f32); `what` names the caller when the lengths
    /// have neither N rows nor one.
    pub(crate) fn with_lengths(
        index: Vec<u32>,
        n_rays: usize,
        lengths: &Tensor,
        what: &str,
    ) -> Result<Self> {
        let (rows, s, _) = lengths.dims3()?;
        anyhow::ensure!(
            rows == n_rays || rows == 1,
            "{what}: lengths have {rows} rows for {n_rays} rays"
        );
        let lengths = lengths
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        Ok(Self::new(index, lengths, (n_rays, s)))
    }

    /// The samples `index` of `n` rays of `s` samples grouped by ray, given every sample's
    /// length (`n·s` values) or one row of `s` shared by all rays.
    pub fn new(index: Vec<u32>, lengths: Vec<f32>, (n, s): (usize, usize)) -> Self {
        // A counting sort by ray, then sample order within each ray.
        let mut start = vec![0usize; n + 1];
        for &k in &index {
            start[k as usize / s + 1] += 1;
        }
        for r in 0..n {
            start[r + 1] += start[r];
        }
        let mut fill = start.clone();
        let mut order = vec![0u32; index.len()];
        for (e, &k) in index.iter().enumerate() {
            let r = k as usize / s;
            order[fill[r]] = e as u32;
            fill[r] += 1;
        }
        for r in 0..n {
            order[start[r]..start[r + 1]].sort_unstable_by_key(|&e| index[e as usize]);
        }
        Self {
            n,
            s,
            index,
            start,
            order,
            lengths,
        }
    }

    /// Ray `ray`'s sample lengths, `S`.
    pub(crate) fn ray_lengths(&self, ray: usize) -> &[f32] {
        let row = if self.lengths.len() == self.s { 0 } else { ray };
        &self.lengths[row * self.s..(row + 1) * self.s]
    }

    /// Ray `ray`'s entries (sample order) with each one's sample position `i`, spacing `Δ` and
    /// optical depth `τ` from `density`.
    pub(crate) fn walk<'a>(
        &'a self,
        ray: usize,
        density: &'a [f32],
    ) -> impl Iterator<Item = (usize, usize, f32, f32)> + 'a {
        let t_ray = self.ray_lengths(ray);
        self.order[self.start[ray]..self.start[ray + 1]]
            .iter()
            .map(move |&e| {
                let e = e as usize;
                let i = self.index[e] as usize % self.s;
                let delta = spacing(t_ray, i);
                (e, i, delta, clamped_optical_depth(density[e], delta))
            })
    }
}

/// Colour, depth and opacity of N rays, `(N, C + 2)` row-major, from the packed samples of a
/// skipping render (see [`composite_packed`]), as slices.
pub fn packed_forward(rays: &PackedRays, density: &[f32], feature: &[f32], c: usize) -> Vec<f32> {
    let width = c + 2;
    let mut out = vec![0f32; rays.n * width];
    out.par_chunks_mut(width).enumerate().for_each(|(ray, o)| {
        let t_ray = rays.ray_lengths(ray);
        let mut t = 1f32;
        for (e, i, _, tau) in rays.walk(ray, density) {
            let a = (-tau).exp();
            let w = t * (1.0 - a);
            t *= a;
            for (o, v) in o[..c].iter_mut().zip(&feature[e * c..(e + 1) * c]) {
                *o += w * v;
            }
            o[c] += w * t_ray[i];
            o[c + 1] += w;
        }
    });
    out
}

/// Colour `(N, C)`, depth and opacity `(N, 1)` of N rays from the packed samples of a skipping
/// render ([`PackedValues`]), given `lengths` `(N, S, 1)`, every sample's length, or
/// `(1, S, 1)` lengths shared by all rays. Samples not listed have σ = 0.
/// This is what [`composite`] gives on the dense tensors with zeros at the skipped samples,
/// bit for bit (a zero optical depth leaves the transmittance and the sums unchanged), but
/// only the listed samples are visited, forward and backward. Differentiable in `density`
/// and `feature`. The fused kernel where [`use_fused`] allows, else its twin
/// `composite_packed_tensor_ops`.
pub fn composite_packed(values: PackedValues, lengths: &Tensor) -> Result<Composited> {
    if !use_fused(&values.density) {
        return composite_packed_tensor_ops(values, lengths);
    }
    let PackedValues {
        index,
        n_rays,
        density,
        feature,
    } = values;
    let c = feature.dim(1)?;
    let rays = PackedRays::with_lengths(index, n_rays, lengths, "composite_packed")?;
    let (density, feature) = (density.contiguous()?, feature.contiguous()?);
    let op = Fused(PackedComposite { rays, c });
    let out = if density.track_op() || feature.track_op() {
        density.apply_op2(&feature, op)?
    } else {
        density.apply_op2_no_bwd(&feature, &op)?
    };
    Composited::from_columns(&out, c)
}

/// The twin of [`composite_packed`] (any device and dtype): the packed values scattered into
/// dense `(N, S, ·)` tensors, zeros at the samples not listed (`index_add`, differentiable),
/// then [`composite_tensor_ops`].
pub(crate) fn composite_packed_tensor_ops(
    values: PackedValues,
    lengths: &Tensor,
) -> Result<Composited> {
    let rays = (values.n_rays, lengths.dim(1)?);
    let (density, feature) = scatter_packed(values.index, rays, &values.density, &values.feature)?;
    let lengths = lengths_per_ray(lengths, rays.0, density.dtype())?;
    composite_tensor_ops(&density, &feature, &lengths)
}

/// `lengths` `(N, S, 1)`, or `(1, S, 1)` shared by all rays, as a contiguous `(N, S, 1)`
/// tensor of `dtype` for `n_rays` rays.
pub(crate) fn lengths_per_ray(lengths: &Tensor, n_rays: usize, dtype: DType) -> Result<Tensor> {
    let (rows, s, _) = lengths.dims3()?;
    anyhow::ensure!(
        rows == n_rays || rows == 1,
        "packed samples: lengths have {rows} rows for {n_rays} rays"
    );
    Ok(lengths
        .to_dtype(dtype)?
        .broadcast_as((n_rays, s, 1))?
        .contiguous()?)
}

/// Packed rows `values` `(M, C)`, listed by flat sample index `ray · S + i` in `index` (a
/// `(M,)` u32 tensor on their device, no repeats), scattered into `(N, S, C)` with zeros at
/// the samples not listed; differentiable (`index_add`), any device and dtype.
pub(crate) fn scatter_rows(
    index: &Tensor,
    (n_rays, s): (usize, usize),
    values: &Tensor,
) -> Result<Tensor> {
    let c = values.dim(1)?;
    let (device, dtype) = (values.device(), values.dtype());
    let mut dense = Tensor::zeros((n_rays * s, c), dtype, device)?;
    if index.dim(0)? > 0 {
        dense = dense.index_add(index, &values.contiguous()?, 0)?;
    }
    Ok(dense.reshape((n_rays, s, c))?)
}

/// Packed values scattered into dense tensors: `density` `(M, 1)` and `feature` `(M, C)`,
/// listed by flat sample index `ray · S + i` in `index` (no repeats), become `(N, S, 1)` and
/// `(N, S, C)` with zeros at the samples not listed; differentiable (`index_add`), any device
/// and dtype.
pub fn scatter_packed(
    index: Vec<u32>,
    rays: (usize, usize),
    density: &Tensor,
    feature: &Tensor,
) -> Result<(Tensor, Tensor)> {
    // One copy of the indices to the device, read by both scatters.
    let m = index.len();
    let index = Tensor::from_vec(index, m, density.device())?;
    Ok((
        scatter_rows(&index, rays, density)?,
        scatter_rows(&index, rays, feature)?,
    ))
}

struct PackedComposite {
    rays: PackedRays,
    c: usize,
}

impl CpuKernel<2> for PackedComposite {
    const NAME: &'static str = "packed-composite";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [density, feature] = CpuInput::all_f32(&inputs, "packed composite")?;
        let m = self.rays.index.len();
        if density.len() != m || feature.len() != m * self.c {
            candle_core::bail!(
                "packed composite: {} densities and {} feature values for {m} samples",
                density.len(),
                feature.len()
            );
        }
        let out = packed_forward(&self.rays, density, feature, self.c);
        Ok((out, Shape::from((self.rays.n, self.c + 2))))
    }

    /// The dense backward pass ([`CompositeBackward`]) restricted to the listed samples.
    fn gradients(&self, [density, feature]: [&Tensor; 2], grad: &Tensor) -> KernelGradients<2> {
        let [sigma, values, go] = host_values([density, feature, grad])?;
        let (g_sigma, g_values) = packed_backward(&self.rays, &sigma, &values, &go, self.c);
        let dev = density.device();
        Ok([
            Some(Tensor::from_vec(g_sigma, density.shape(), dev)?),
            Some(Tensor::from_vec(g_values, feature.shape(), dev)?),
        ])
    }
}

/// The backward pass of [`packed_forward`]: from the output gradient `go_all` `(N, C + 2)`
/// (colour, depth, opacity), the gradients of the packed densities `(M)` and features
/// `(M, C)`, on host values.
pub fn packed_backward(
    rays: &PackedRays,
    sigma: &[f32],
    values: &[f32],
    go_all: &[f32],
    c: usize,
) -> (Vec<f32>, Vec<f32>) {
    let width = c + 2;
    // Per ray: (entry, ∂L/∂σ, ∂L/∂v) of each of its samples.
    let per_ray: Vec<Vec<(usize, f32, Vec<f32>)>> = (0..rays.n)
        .into_par_iter()
        .map(|ray| {
            let go = &go_all[ray * width..(ray + 1) * width];
            let t_ray = rays.ray_lengths(ray);
            let mut t = 1f32;
            // (entry, Δ, σΔ, w, T after, g) front to back.
            let walked: Vec<(usize, f32, f32, f32, f32, f32)> = rays
                .walk(ray, sigma)
                .map(|(e, i, delta, tau)| {
                    let a = (-tau).exp();
                    let w = t * (1.0 - a);
                    t *= a;
                    let v = &values[e * c..(e + 1) * c];
                    let g = go[c] * t_ray[i]
                        + go[c + 1]
                        + v.iter().zip(&go[..c]).map(|(v, g)| v * g).sum::<f32>();
                    (e, delta, sigma[e] * delta, w, t, g)
                })
                .collect();
            let mut suffix = 0f32;
            let mut out = Vec::with_capacity(walked.len());
            for &(e, delta, raw, w, t_after, g) in walked.iter().rev() {
                let d_tau = t_after * g - suffix;
                suffix += w * g;
                let active = (0.0..MAX_OPTICAL_DEPTH as f32).contains(&raw);
                let gs = if active { delta * d_tau } else { 0.0 };
                out.push((e, gs, go[..c].iter().map(|g| w * g).collect()));
            }
            out
        })
        .collect();
    let m = rays.index.len();
    let mut g_sigma = vec![0f32; m];
    let mut g_values = vec![0f32; m * c];
    for (e, gs, gv) in per_ray.into_iter().flatten() {
        g_sigma[e] = gs;
        g_values[e * c..(e + 1) * c].copy_from_slice(&gv);
    }
    (g_sigma, g_values)
}

/// [`composite`] as Candle tensor ops ([`weights`] and [`aggregate`]; any device, differentiable).
///
/// `density`, `lengths`: `(N, S, 1)`; `feature`: `(N, S, C)`. Returns colour `(N, C)`, depth
/// `(N, 1)` and opacity `(N, 1)`.
pub(crate) fn composite_tensor_ops(
    density: &Tensor,
    feature: &Tensor,
    lengths: &Tensor,
) -> Result<Composited> {
    let w = weights(density, &deltas(lengths)?)?;
    Ok(Composited {
        color: aggregate(&w, feature)?,
        depth: aggregate(&w, lengths)?,
        opacity: w.sum(1)?,
    })
}

/// A read-only `(N, S, K)` view with arbitrary strides.
#[derive(Clone, Copy)]
struct View<'a> {
    data: &'a [f32],
    offset: usize,
    strides: [usize; 3],
}

impl<'a> View<'a> {
    fn new(input: CpuInput<'a>) -> candle_core::Result<Self> {
        let (storage, layout) = (input.storage, input.layout);
        let st = layout.stride();
        if st.len() != 3 {
            candle_core::bail!(
                "composite: expected a rank-3 tensor, got {:?}",
                layout.shape()
            );
        }
        Ok(Self {
            data: storage.as_slice::<f32>()?,
            offset: layout.start_offset(),
            strides: [st[0], st[1], st[2]],
        })
    }

    #[inline]
    fn at(&self, ray: usize, sample: usize, channel: usize) -> f32 {
        self.data[self.offset
            + ray * self.strides[0]
            + sample * self.strides[1]
            + channel * self.strides[2]]
    }
}

/// Per-ray scratch: optical depths, weights, transmittance after each sample, spacings.
struct Scratch {
    tau: Vec<f32>,
    w: Vec<f32>,
    t_after: Vec<f32>,
    delta: Vec<f32>,
    length: Vec<f32>,
}

impl Scratch {
    fn new(s: usize) -> Self {
        Self {
            tau: vec![0.0; s],
            w: vec![0.0; s],
            t_after: vec![0.0; s],
            delta: vec![0.0; s],
            length: vec![0.0; s],
        }
    }

    /// Fills spacings, optical depths and weights of one ray.
    fn ray(&mut self, sigma: &View, lengths: &View, ray: usize) {
        let s = self.tau.len();
        for i in 0..s {
            self.length[i] = lengths.at(ray, i, 0);
        }
        for i in 0..s {
            self.delta[i] = spacing(&self.length, i);
            self.tau[i] = clamped_optical_depth(sigma.at(ray, i, 0), self.delta[i]);
        }
        ray_weights(&self.tau, &mut self.w, &mut self.t_after);
    }
}

/// The forward op: `(σ, t, v) → (N, C + 2)`.
pub(crate) struct Composite;

impl CpuKernel<3> for Composite {
    const NAME: &'static str = "volume-composite";

    fn cpu_forward(&self, [s1, s2, s3]: [CpuInput; 3]) -> KernelOutput {
        let (sigma, lengths, values) = (View::new(s1)?, View::new(s2)?, View::new(s3)?);
        let (n, s, k) = s3.shape().dims3()?;
        if s1.shape().dims3()? != (n, s, 1) || s2.shape().dims3()? != (n, s, 1) {
            candle_core::bail!("composite: density, lengths and features disagree in shape");
        }
        let width = k + 2;
        let mut out = vec![0f32; n * width];
        out.par_chunks_mut(RAYS_PER_TASK * width)
            .enumerate()
            .for_each(|(task, out)| {
                let mut sc = Scratch::new(s);
                for (r, o) in out.chunks_exact_mut(width).enumerate() {
                    let ray = task * RAYS_PER_TASK + r;
                    sc.ray(&sigma, &lengths, ray);
                    o.fill(0.0);
                    for i in 0..s {
                        let w = sc.w[i];
                        for c in 0..k {
                            o[c] += w * values.at(ray, i, c);
                        }
                        o[k] += w * lengths.at(ray, i, 0);
                        o[k + 1] += w;
                    }
                }
            });
        Ok((out, Shape::from((n, width))))
    }

    fn gradients(
        &self,
        [sigma, lengths, values]: [&Tensor; 3],
        grad: &Tensor,
    ) -> KernelGradients<3> {
        let (n, s, k) = values.dims3()?;
        let packed = Tensor::cat(
            &[
                &sigma.flatten_all()?,
                &lengths.flatten_all()?,
                &grad.flatten_all()?,
            ],
            0,
        )?;
        let both = packed.apply_op2_no_bwd(&values.contiguous()?, &Fused(CompositeBackward))?;
        let grad_sigma = both.narrow(0, 0, n * s)?.reshape((n, s, 1))?;
        let grad_values = both.narrow(0, n * s, n * s * k)?.reshape((n, s, k))?;
        Ok([Some(grad_sigma), None, Some(grad_values)])
    }
}

/// The backward op: `[σ, t, G]` flattened and concatenated, and v `(N, S, C)` →
/// `[∂L/∂σ, ∂L/∂v]` flattened and concatenated.
struct CompositeBackward;

impl CpuKernel<2> for CompositeBackward {
    const NAME: &'static str = "volume-composite-backward";

    fn cpu_forward(&self, [packed, values]: [CpuInput; 2]) -> KernelOutput {
        let (n, s, k) = values.shape().dims3()?;
        let values = View::new(values)?;
        let packed = packed.f32("composite backward")?;
        let (sigma_flat, rest) = packed.split_at(n * s);
        let (lengths_flat, grad) = rest.split_at(n * s);
        let sigma = View {
            data: sigma_flat,
            offset: 0,
            strides: [s, 1, 1],
        };
        let lengths = View {
            data: lengths_flat,
            offset: 0,
            strides: [s, 1, 1],
        };
        let width = k + 2;
        let mut out = vec![0f32; n * s * (k + 1)];
        let (g_sigma, g_values) = out.split_at_mut(n * s);
        g_sigma
            .par_chunks_mut(RAYS_PER_TASK * s)
            .zip(g_values.par_chunks_mut(RAYS_PER_TASK * s * k))
            .enumerate()
            .for_each(|(task, (gs, gv))| {
                let mut sc = Scratch::new(s);
                let mut g = vec![0f32; s];
                for (r, (gs, gv)) in gs
                    .chunks_exact_mut(s)
                    .zip(gv.chunks_exact_mut(s * k))
                    .enumerate()
                {
                    let ray = task * RAYS_PER_TASK + r;
                    let go = &grad[ray * width..(ray + 1) * width];
                    sc.ray(&sigma, &lengths, ray);
                    for i in 0..s {
                        let mut gi = go[k] * lengths.at(ray, i, 0) + go[k + 1];
                        for c in 0..k {
                            gi += go[c] * values.at(ray, i, c);
                            gv[i * k + c] = sc.w[i] * go[c];
                        }
                        g[i] = gi;
                    }
                    // Suffix sums Σ_{j>i} w_j g_j, walking backwards.
                    let mut suffix = 0f32;
                    for i in (0..s).rev() {
                        let d_tau = sc.t_after[i] * g[i] - suffix;
                        suffix += sc.w[i] * g[i];
                        let raw = sigma.at(ray, i, 0) * sc.delta[i];
                        let active = (0.0..MAX_OPTICAL_DEPTH as f32).contains(&raw);
                        gs[i] = if active { sc.delta[i] * d_tau } else { 0.0 };
                    }
                }
            });
        Ok((out, Shape::from(n * s * (k + 1))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use nerf_core::compare::assert_close;

    /// Random inputs; `zero` is the value used for the 30% empty samples.
    fn inputs(n: usize, s: usize, k: usize, seed: u64, zero: f32) -> (Tensor, Tensor, Tensor) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let sigma: Vec<f32> = (0..n * s)
            .map(|_| {
                if rng.random::<f32>() < 0.3 {
                    zero
                } else {
                    rng.random::<f32>() * 4.0
                }
            })
            .collect();
        let mut lengths = Vec::new();
        for _ in 0..n {
            let mut t = 0.5f32;
            for _ in 0..s {
                t += rng.random::<f32>() * 0.2;
                lengths.push(t);
            }
        }
        let values: Vec<f32> = (0..n * s * k).map(|_| rng.random::<f32>()).collect();
        let dev = &Device::Cpu;
        let l = Tensor::from_vec(lengths, (n, s, 1), dev).unwrap();
        (
            Tensor::from_vec(sigma, (n, s, 1), dev).unwrap(),
            l,
            Tensor::from_vec(values, (n, s, k), dev).unwrap(),
        )
    }

    #[test]
    fn forward_matches_tensor_ops() {
        let (sigma, l, v) = inputs(300, 9, 4, 1, 0.0);
        // A strided feature view, as the fused SDF field hands over.
        let wide = Tensor::cat(&[&v, &v], 2).unwrap();
        let v_view = wide.narrow(2, 4, 4).unwrap();
        let fused = sigma.apply_op3(&l, &v_view, Fused(Composite)).unwrap();
        assert_eq!(fused.dims(), &[300, 6]);
        let w = weights(&sigma, &deltas(&l).unwrap()).unwrap();
        let reference = Tensor::cat(
            &[
                aggregate(&w, &v).unwrap(),
                aggregate(&w, &l).unwrap(),
                w.sum(1).unwrap(),
            ],
            1,
        )
        .unwrap();
        let diff = nerf_core::compare::max_abs_difference(&fused, &reference).unwrap();
        assert!(diff < 1e-5, "max diff {diff}");
    }

    #[test]
    fn backward_matches_tensor_ops_autodiff() {
        // Exact zeros are avoided: Candle's clamp splits the gradient at a tie.
        let (sigma, l, v) = inputs(70, 12, 3, 2, 1e-4);
        let d = deltas(&l).unwrap();
        let sv = Var::from_tensor(&sigma).unwrap();
        let vv = Var::from_tensor(&v).unwrap();
        // A loss that weights every output differently.
        let mix = Tensor::new(&[[0.3f32, -1.2, 0.7, 0.4, 2.0]], &Device::Cpu).unwrap();
        let loss_of = |out: Tensor| out.broadcast_mul(&mix).unwrap().sum_all().unwrap();
        let fused = loss_of(
            sv.as_tensor()
                .apply_op3(&l, vv.as_tensor(), Fused(Composite))
                .unwrap(),
        );
        let gf = fused.backward().unwrap();
        let w = weights(sv.as_tensor(), &d).unwrap();
        let reference = loss_of(
            Tensor::cat(
                &[
                    aggregate(&w, vv.as_tensor()).unwrap(),
                    aggregate(&w, &l).unwrap(),
                    w.sum(1).unwrap(),
                ],
                1,
            )
            .unwrap(),
        );
        let gr = reference.backward().unwrap();
        for var in [&sv, &vv] {
            let (a, b) = (gf.get(var).unwrap(), gr.get(var).unwrap());
            assert_close(a, b, 1e-4, "gradient");
        }
    }

    #[test]
    fn packed_kernel_matches_its_tensor_op_twin_values_and_gradients() {
        let (n, s_len, c) = (40, 10, 3);
        let (_, l, _) = inputs(n, s_len, c, 3, 0.0);
        // Every third sample listed, in a shuffled order.
        let mut index: Vec<u32> = (0..(n * s_len) as u32).filter(|i| i % 3 != 1).collect();
        index.reverse();
        let m = index.len();
        let dev = &Device::Cpu;
        let sigma = Var::from_tensor(&Tensor::rand(0f32, 3.0, (m, 1), dev).unwrap()).unwrap();
        let feature = Var::from_tensor(&Tensor::rand(0f32, 1.0, (m, c), dev).unwrap()).unwrap();
        let mix = Tensor::new(&[[0.3f32, -1.2, 0.7]], dev).unwrap();
        let loss = |out: Composited| {
            let parts = [
                out.color.broadcast_mul(&mix).unwrap().sum_all().unwrap(),
                out.depth.sum_all().unwrap().affine(0.4, 0.0).unwrap(),
                out.opacity.sum_all().unwrap().affine(2.0, 0.0).unwrap(),
            ];
            ((&parts[0] + &parts[1]).unwrap() + &parts[2]).unwrap()
        };
        let (s_t, f_t) = (sigma.as_tensor(), feature.as_tensor());
        let values = PackedValues {
            index,
            n_rays: n,
            density: s_t.clone(),
            feature: f_t.clone(),
        };
        let fused = loss(composite_packed(values.clone(), &l).unwrap());
        let twin = loss(composite_packed_tensor_ops(values, &l).unwrap());
        let (a, b) = (
            fused.to_scalar::<f32>().unwrap(),
            twin.to_scalar::<f32>().unwrap(),
        );
        assert!((a - b).abs() <= 1e-4 * b.abs().max(1.0), "{a} vs {b}");
        let (gf, gt) = (fused.backward().unwrap(), twin.backward().unwrap());
        for var in [&sigma, &feature] {
            let d = nerf_core::compare::max_abs_difference(
                gf.get(var.as_tensor()).unwrap(),
                gt.get(var.as_tensor()).unwrap(),
            )
            .unwrap();
            assert!(d < 1e-4, "gradient differs by {d}");
        }
    }
}
