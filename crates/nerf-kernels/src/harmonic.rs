//! The NeRF's harmonic embedding `[sin(x·f), cos(x·f), x]`, `f = 2^0 … 2^(L−1)`, as one fused
//! CPU op with a hand-written backward pass.
//!
//! Through Candle ops it is a broadcast product, two element-wise libm calls per value and a
//! concatenation: 20 `sinf`/`cosf` calls a coordinate at the homework's 10 frequencies. Here
//! each coordinate takes one `sin` and one `cos` in f64 every 8 frequencies, and the doubling
//! formulas `sin 2a = 2·sin a·cos a`, `cos 2a = cos²a − sin²a` in f64 between them: each
//! doubling at most doubles the error, so after 7 it is under 2^7 · 2^-52 ≈ 3e-14, far below
//! an f32's resolution, and each value rounds to f32 within one unit in the last place of
//! `sinf(x·2^k)` (`x·2^k` is exact in f32, so that is the homework's value). The tensor-op twin
//! is `harmonic_embedding_tensor_ops`.

use candle_core::{Shape, Tensor};
use rayon::prelude::*;

use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use crate::storage::host_values;
use crate::use_fused;

/// Doublings between two direct evaluations of `sin` and `cos`.
const DOUBLINGS: usize = 8;

/// Rows a task embeds.
const ROWS_PER_TASK: usize = 4096;

/// `[sin(x·f), cos(x·f), x]` with `f = 2^0 … 2^(L−1)`, ordered as pytorch3d's
/// `HarmonicEmbedding` (coordinate-major within each of the sin and cos blocks): the fused op
/// where [`use_fused`] allows, else `harmonic_embedding_tensor_ops`.
///
/// `x`: `(M, C)`; returns `(M, C·2L + C)` (`x` itself when `L = 0`).
pub fn harmonic_embedding(x: &Tensor, n_frequencies: usize) -> candle_core::Result<Tensor> {
    if n_frequencies == 0 {
        return Ok(x.clone());
    }
    if !use_fused(x) {
        return harmonic_embedding_tensor_ops(x, n_frequencies);
    }
    let (_, c) = x.dims2()?;
    let op = Fused(Harmonic { c, n_frequencies });
    let x = x.contiguous()?;
    if x.track_op() {
        x.apply_op1(op)
    } else {
        x.apply_op1_no_bwd(&op)
    }
}

/// The tensor-op twin of [`harmonic_embedding`] (any device and dtype, differentiable).
///
/// `x`: `(M, C)`; returns `(M, C·2L + C)`.
pub(crate) fn harmonic_embedding_tensor_ops(
    x: &Tensor,
    n_frequencies: usize,
) -> candle_core::Result<Tensor> {
    let (m, c) = x.dims2()?;
    if n_frequencies == 0 {
        return Ok(x.clone());
    }
    let freqs: Vec<f32> = (0..n_frequencies).map(|i| 2f32.powi(i as i32)).collect();
    let freqs = Tensor::from_vec(freqs, (1, 1, n_frequencies), x.device())?.to_dtype(x.dtype())?;
    let embed = x
        .unsqueeze(2)?
        .broadcast_mul(&freqs)?
        .reshape((m, c * n_frequencies))?;
    Tensor::cat(&[&embed.sin()?, &embed.cos()?, x], 1)
}

/// `(sin(v·2^k), cos(v·2^k))` for `k = 0 … n−1` into `sin` and `cos` (`n` each).
fn sin_cos_doublings(v: f32, sin: &mut [f32], cos: &mut [f32]) {
    let (mut s, mut c) = (0f64, 1f64);
    for (k, (sk, ck)) in sin.iter_mut().zip(cos.iter_mut()).enumerate() {
        if k % DOUBLINGS == 0 {
            // `v·2^k` is exact in f64 (and in f32, short of overflow).
            (s, c) = (v as f64 * 2f64.powi(k as i32)).sin_cos();
        } else {
            (s, c) = (2.0 * s * c, c * c - s * s);
        }
        *sk = s as f32;
        *ck = c as f32;
    }
}

struct Harmonic {
    /// Coordinates a row (`C`).
    c: usize,
    /// Frequencies (`L`).
    n_frequencies: usize,
}

impl Harmonic {
    fn width(&self) -> usize {
        self.c * (2 * self.n_frequencies + 1)
    }
}

impl CpuKernel<1> for Harmonic {
    const NAME: &'static str = "harmonic-embedding";

    fn cpu_forward(&self, inputs: [CpuInput; 1]) -> KernelOutput {
        let [x] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let (c, l, w) = (self.c, self.n_frequencies, self.width());
        let m = x.len() / c;
        let mut out = vec![0f32; m * w];
        out.par_chunks_mut(ROWS_PER_TASK * w)
            .zip(x.par_chunks(ROWS_PER_TASK * c))
            .for_each(|(out, x)| {
                for (row, x) in out.chunks_exact_mut(w).zip(x.chunks_exact(c)) {
                    let (sin, rest) = row.split_at_mut(c * l);
                    let (cos, copy) = rest.split_at_mut(c * l);
                    for (d, &v) in x.iter().enumerate() {
                        let span = d * l..(d + 1) * l;
                        sin_cos_doublings(v, &mut sin[span.clone()], &mut cos[span]);
                    }
                    copy.copy_from_slice(x);
                }
            });
        Ok((out, Shape::from((m, w))))
    }

    /// `∂L/∂x_d = g_x[d] + Σ_k 2^k (g_sin[d,k]·cos(x_d·2^k) − g_cos[d,k]·sin(x_d·2^k))`.
    fn gradients(&self, [x]: [&Tensor; 1], grad: &Tensor) -> KernelGradients<1> {
        let (c, l, w) = (self.c, self.n_frequencies, self.width());
        let [xs, g] = host_values([x, grad])?;
        let mut dx = vec![0f32; xs.len()];
        let (mut sin, mut cos) = (vec![0f32; l], vec![0f32; l]);
        for ((dx, x), g) in dx
            .chunks_exact_mut(c)
            .zip(xs.chunks_exact(c))
            .zip(g.chunks_exact(w))
        {
            for (d, &v) in x.iter().enumerate() {
                sin_cos_doublings(v, &mut sin, &mut cos);
                let (g_sin, g_cos) = (
                    &g[d * l..(d + 1) * l],
                    &g[c * l + d * l..c * l + (d + 1) * l],
                );
                let mut sum = g[2 * c * l + d] as f64;
                for k in 0..l {
                    let f = 2f64.powi(k as i32);
                    sum += f * (g_sin[k] as f64 * cos[k] as f64 - g_cos[k] as f64 * sin[k] as f64);
                }
                dx[d] = sum as f32;
            }
        }
        Ok([Some(Tensor::from_vec(dx, x.shape(), x.device())?)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{uniform_values, weighted_sum_gradients};
    use candle_core::{Device, Var};
    use nerf_core::compare::{assert_close, max_abs_difference};

    #[test]
    fn fused_matches_tensor_ops_and_float64_forward_and_backward() {
        let dev = Device::Cpu;
        // Up to 20 frequencies (three direct evaluations) on points out to ±4.
        for l in [1, 2, 6, 10, 20] {
            let x = Var::from_vec(uniform_values(300, 3, -4f32, 4.0), (100, 3), &dev).unwrap();
            let fast = harmonic_embedding(&x, l).unwrap();
            let slow = harmonic_embedding_tensor_ops(&x, l).unwrap();
            assert_eq!(fast.dims(), [100, 3 * (2 * l + 1)]);
            // Each value within one f32 unit of sin/cos in float64 of the exact argument.
            let values = fast.to_vec2::<f32>().unwrap();
            for (row, p) in values.iter().zip(x.to_vec2::<f32>().unwrap()) {
                for d in 0..3 {
                    for k in 0..l {
                        let a = p[d] as f64 * 2f64.powi(k as i32);
                        let (s, c) = (row[d * l + k] as f64, row[3 * l + d * l + k] as f64);
                        assert!((s - a.sin()).abs() <= 6e-8, "sin {a}: {s}");
                        assert!((c - a.cos()).abs() <= 6e-8, "cos {a}: {c}");
                    }
                    assert_eq!(row[6 * l + d], p[d]);
                }
            }
            let diff = max_abs_difference(&fast, &slow).unwrap();
            assert!(diff <= 2.5e-7, "{l} frequencies: {diff}");
            let weight = Tensor::randn(0f32, 1.0, fast.dims(), &dev).unwrap();
            let (gf, gs) = (
                weighted_sum_gradients(&fast, &weight),
                weighted_sum_gradients(&slow, &weight),
            );
            // The gradient scales with 2^(L−1): compared relative to that.
            let scale = 2f32.powi(l as i32 - 1);
            let (a, b) = (gf.get(&x).unwrap(), gs.get(&x).unwrap());
            let (a, b) = ((a / scale as f64).unwrap(), (b / scale as f64).unwrap());
            assert_close(&a, &b, 1e-5, &format!("{l} frequencies"));
        }
    }
}
