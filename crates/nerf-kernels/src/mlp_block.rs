//! Dense layers on one task's rows, on the calling thread: what the fused MLP kernels
//! ([`crate::nerf_mlp`], and `nerf_hash_grid::ngp_mlp`) build their passes from.
//!
//! A task takes [`ROWS_PER_TASK`] samples through every layer while they sit in cache; its
//! backward pass adds the weight gradients into a per-block buffer, and the blocks' buffers are
//! added in block order ([`GradientSums::add_in_order`]), so a result does not depend on how the work was
//! shared between threads (a resumed run repeats an uninterrupted one bit for bit).
//!
//! Weights are row-major `(out, in)` as PyTorch's `nn.Linear`; every matrix is given with its
//! row stride, so that a layer can read or write a block of columns of a wider one (a skip
//! layer's two inputs, the NGP colour MLP's geometry columns).

use std::collections::HashMap;
use std::sync::Mutex;

use crate::gemm::gemm_f32;

/// Rows a task takes through every layer at once.
pub const ROWS_PER_TASK: usize = 256;

/// Tasks whose gradients one backward block sums before the blocks are added in order.
pub const BLOCKS_PER_SUM: usize = 8;

/// A matrix `B` read from a weight slice: `B[i][j]` at `slice[i·rs + j·cs]`.
pub(crate) type Strided<'a> = (&'a [f32], (usize, usize));

/// Task buffers kept for reuse, by length, with the number of floats they hold.
struct SpareBuffers {
    by_len: Option<HashMap<usize, Vec<Vec<f32>>>>,
    floats: usize,
}

static SPARE: Mutex<SpareBuffers> = Mutex::new(SpareBuffers {
    by_len: None,
    floats: 0,
});

/// The most the spare buffers hold: 512 MiB of f32 (the dense training step's activations,
/// 1024 rays × 128 samples, take about as much).
const SPARE_FLOATS: usize = 1 << 27;

/// A buffer of `len` floats whose values are unspecified: a reused one keeps what it held, a
/// new one is zero. For a task's activations and gradients, each of which `gemm` overwrites in
/// full before it is read; fresh zeroed allocations took a measurable share of the dense
/// training step (docs/speed-and-report.md#allocators).
pub fn task_buffer(len: usize) -> Vec<f32> {
    let mut spare = SPARE.lock().unwrap_or_else(|e| e.into_inner());
    let reused = spare
        .by_len
        .as_mut()
        .and_then(|m| m.get_mut(&len))
        .and_then(|list| list.pop());
    match reused {
        Some(v) => {
            spare.floats -= v.len();
            v
        }
        None => {
            drop(spare);
            vec![0.0; len]
        }
    }
}

/// Keeps `buffers` for [`task_buffer`], up to 512 MiB of f32 in all (the rest are freed).
pub fn recycle(buffers: impl IntoIterator<Item = Vec<f32>>) {
    let mut spare = SPARE.lock().unwrap_or_else(|e| e.into_inner());
    for v in buffers {
        if v.is_empty() || spare.floats + v.len() > SPARE_FLOATS {
            continue;
        }
        spare.floats += v.len();
        let by_len = spare.by_len.get_or_insert_with(HashMap::new);
        by_len.entry(v.len()).or_default().push(v);
    }
}

/// `Wᵀ` `(k, n)` of a row-major weight `W` `(n, k)` with row stride `w_rs`: a layer's forward
/// product `x·Wᵀ`.
pub fn transposed(w: &[f32], w_rs: usize) -> Strided<'_> {
    (w, (1, w_rs))
}

/// A row-major weight `W` `(k, n)` with row stride `w_rs` as it is: a gradient `D·W` passed
/// back through the layer.
pub fn as_is(w: &[f32], w_rs: usize) -> Strided<'_> {
    (w, (w_rs, 1))
}

/// `out (c×n) [+]= x · B` for `x` `(c, k)` with row stride `x_rs` and `B` `(k, n)`
/// ([`transposed`] or [`as_is`]); `out` is contiguous.
pub fn times(
    out: &mut [f32],
    accumulate: bool,
    (x, x_rs): (&[f32], usize),
    (b, b_strides): Strided,
    (c, k, n): (usize, usize, usize),
) {
    if k == 0 && !accumulate {
        // An empty product: `out` may be a reused buffer ([`task_buffer`]), so it is cleared
        // here rather than left to what `gemm` does with no terms.
        out[..c * n].fill(0.0);
        return;
    }
    gemm_f32(
        (c, n, k),
        out,
        n,
        accumulate,
        x,
        (x_rs, 1),
        b,
        b_strides,
        false,
    );
}

/// `out (c×n) = x · Wᵀ + b` for contiguous `x` `(c, k)`, `W` `(n, k)` and `b` `(n)`.
pub fn linear(out: &mut [f32], x: &[f32], (c, k, n): (usize, usize, usize), w: &[f32], b: &[f32]) {
    times(out, false, (x, k), transposed(w, k), (c, k, n));
    add_bias(out, b);
}

/// Adds `b` `(n)` to every row of `out` `(c, n)`.
pub(crate) fn add_bias(out: &mut [f32], b: &[f32]) {
    for row in out.chunks_exact_mut(b.len()) {
        row.iter_mut().zip(b).for_each(|(v, b)| *v += b);
    }
}

/// `max(v, 0)` in place.
pub fn relu(v: &mut [f32]) {
    v.iter_mut().for_each(|x| *x = x.max(0.0));
}

/// `d ⊙ [y > 0]` (the ReLU's backward through its output `y`), in place.
pub fn mask(d: &mut [f32], y: &[f32]) {
    d.iter_mut()
        .zip(y)
        .for_each(|(d, y)| *d = if *y > 0.0 { *d } else { 0.0 });
}

/// `dW (n_out×k, row stride dw_rs) += Dᵀ · X` for `D` `(c, n_out)` contiguous and `X` `(c, k)`
/// with row stride `x_rs`, and `db += Σ_rows D`.
pub fn weight_grad(
    (dw, dw_rs): (&mut [f32], usize),
    db: Option<&mut [f32]>,
    d: &[f32],
    (x, x_rs): (&[f32], usize),
    (c, n_out, k): (usize, usize, usize),
) {
    let (lhs, rhs) = ((d, (1, n_out)), (x, (x_rs, 1)));
    gemm_f32(
        (n_out, k, c),
        dw,
        dw_rs,
        true,
        lhs.0,
        lhs.1,
        rhs.0,
        rhs.1,
        false,
    );
    if let Some(db) = db {
        for row in d.chunks_exact(n_out) {
            db.iter_mut().zip(row).for_each(|(b, v)| *b += v);
        }
    }
}

/// An error naming `op` unless `rays` holds one ray for each of `m` samples, each below `n`.
pub fn check_rays(op: &str, rays: &[u32], m: usize, n: usize) -> candle_core::Result<()> {
    if rays.len() != m {
        candle_core::bail!("{op}: {} ray indices for {m} samples", rays.len());
    }
    if let Some(bad) = rays.iter().find(|&&r| r as usize >= n) {
        candle_core::bail!("{op}: ray index {bad} of {n} rays");
    }
    Ok(())
}

/// `h = relu(h + p_{r(i)})` for every row `i` of `h` `(c, k)`: the per-ray part `per_ray`
/// `(N, k)` of a colour layer added by each row's ray `rays[i]`, then the ReLU.
pub fn add_per_ray_relu(h: &mut [f32], rays: &[u32], per_ray: &[f32]) {
    let k = h.len() / rays.len().max(1);
    for (row, &r) in h.chunks_exact_mut(k).zip(rays) {
        let p = &per_ray[r as usize * k..(r as usize + 1) * k];
        row.iter_mut()
            .zip(p)
            .for_each(|(v, q)| *v = (*v + q).max(0.0));
    }
}

/// `rgb = sigmoid(h·W_oᵀ + b_o)` for `h` `(c, k)`, `W_o` `(3, k)` then `b_o` `(3)` in
/// `w_and_b`; returns `(c, 3)`.
pub fn rgb_head(h: &[f32], w_and_b: &[f32]) -> Vec<f32> {
    let k = (w_and_b.len() - 3) / 3;
    let c = h.len() / k;
    let mut rgb = task_buffer(c * 3);
    let (w, b) = w_and_b.split_at(3 * k);
    linear(&mut rgb, h, (c, k, 3), w, b);
    rgb.iter_mut().for_each(|v| *v = 1.0 / (1.0 + (-*v).exp()));
    rgb
}

/// Back through [`rgb_head`] and the ReLU before it, from the gradient `grad` `(c, 4)` of
/// `[density, r, g, b]` rows: adds `W_o`'s and `b_o`'s gradients into `d_w_and_b` (laid out as
/// `w_and_b`) and returns the gradient of the ReLU's input, `(c, k)`.
pub fn rgb_head_backward(
    (grad, rgb, h): (&[f32], &[f32], &[f32]),
    (w_and_b, d_w_and_b): (&[f32], &mut [f32]),
) -> Vec<f32> {
    let k = (w_and_b.len() - 3) / 3;
    let c = grad.len() / 4;
    let d_rgb: Vec<f32> = grad
        .chunks_exact(4)
        .zip(rgb.chunks_exact(3))
        .flat_map(|(g, y)| (0..3).map(move |j| g[1 + j] * y[j] * (1.0 - y[j])))
        .collect();
    let (dw, db) = d_w_and_b.split_at_mut(3 * k);
    weight_grad((dw, k), Some(db), &d_rgb, (h, k), (c, 3, k));
    let mut d_h = task_buffer(c * k);
    times(
        &mut d_h,
        false,
        (&d_rgb, 3),
        as_is(&w_and_b[..3 * k], k),
        (c, 3, k),
    );
    mask(&mut d_h, h);
    d_h
}

/// Adds each row of `d` `(c, k)` into row `rays[i]` of `d_per_ray` `(N, k)`: the backward pass
/// of [`add_per_ray_relu`]'s addition.
pub fn add_by_ray(d_per_ray: &mut [f32], d: &[f32], rays: &[u32]) {
    let k = d.len() / rays.len().max(1);
    for (row, &r) in d.chunks_exact(k).zip(rays) {
        let dst = &mut d_per_ray[r as usize * k..(r as usize + 1) * k];
        dst.iter_mut().zip(row).for_each(|(s, v)| *s += v);
    }
}

/// One block's gradient sums in a fused MLP's backward pass: its packed parameters' and its
/// per-ray inputs', the latter for the rays its samples lie on only (a window of the `(N·H)`
/// per-ray values starting at `per_ray_offset`), so that a block of a batch of many rays
/// neither zeroes nor adds the whole `(N, H)`.
pub struct GradientSums {
    /// `(P)`, the packed parameters' gradient.
    pub params: Vec<f32>,
    /// The per-ray inputs' gradient, values `per_ray_offset..per_ray_offset + len`.
    pub per_ray: Vec<f32>,
    /// Where `per_ray` starts among all the per-ray values.
    pub per_ray_offset: usize,
}

impl GradientSums {
    /// All zero, for `n_params` parameters and all `n_per_ray` per-ray values.
    pub(crate) fn zeros(n_params: usize, n_per_ray: usize) -> Self {
        Self::zeros_from(n_params, 0, n_per_ray)
    }

    /// All zero, for `n_params` parameters and the `len` per-ray values from `offset`.
    pub fn zeros_from(n_params: usize, offset: usize, len: usize) -> Self {
        Self {
            params: vec![0.0; n_params],
            per_ray: vec![0.0; len],
            per_ray_offset: offset,
        }
    }

    /// Every block's sums added element-wise in block order, into all `n_per_ray` per-ray
    /// values (each block's window at its offset); zeros of those sizes when there are no
    /// blocks. Each value is summed in block order, as when every block held all of them.
    pub fn add_in_order(parts: Vec<Self>, n_params: usize, n_per_ray: usize) -> Self {
        let add = |sum: &mut [f32], part: &[f32]| {
            sum.iter_mut().zip(part).for_each(|(x, y)| *x += y);
        };
        let mut total = Self::zeros(n_params, n_per_ray);
        for part in parts {
            add(&mut total.params, &part.params);
            let window = part.per_ray_offset..part.per_ray_offset + part.per_ray.len();
            add(&mut total.per_ray[window], &part.per_ray);
        }
        total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_overwrite_reused_buffers_in_full() {
        // A stale buffer, as task_buffer may hand out.
        let mut out = vec![7f32; 6];
        let x = [1f32, 2.0, 3.0, 4.0]; // (2, 2)
        let w = [1f32, 0.0, 0.0, 1.0, 1.0, 1.0]; // W (3, 2)
        times(&mut out, false, (&x, 2), transposed(&w, 2), (2, 2, 3));
        assert_eq!(out, [1.0, 2.0, 3.0, 3.0, 4.0, 7.0]);
        // No terms (k = 0): zeros, not the stale values.
        let mut out = vec![7f32; 6];
        times(&mut out, false, (&[], 0), transposed(&[], 0), (2, 0, 3));
        assert_eq!(out, [0.0; 6]);
        // D·W with W (2, 3) as it is: [1 2]·W, [3 4]·W.
        let mut out = vec![7f32; 6];
        times(&mut out, false, (&x, 2), as_is(&w, 3), (2, 2, 3));
        assert_eq!(out, [1.0 + 2.0, 0.0 + 2.0, 0.0 + 2.0, 3.0 + 4.0, 4.0, 4.0]);
    }
}
