//! The NeRF trunk (`mlp_xyz`: ReLU layers with the embedding re-appended before the skip
//! layers) as one fused CPU op with a hand-written backward pass.
//!
//! Through Candle ops, every layer's backward pass allocates a zeroed gradient buffer per
//! activation and adds into it, and the input embedding's gradient (never needed: the points
//! are data) is computed too. Here the forward pass runs each layer as one `gemm` (two for a
//! skip layer: `[y, x]·Wᵀ = y·W_yᵀ + x·W_xᵀ`, no concatenation) plus a fused bias + ReLU, and
//! keeps the layer outputs; the backward pass walks the layers once, writing weight and bias
//! gradients straight into one flat buffer. Other devices (and f64, and `--kernels generic`) use
//! the tensor-op twin [`trunk_tensor_ops`].
//!
//! Parameters are passed packed: for each layer `W_i` `(H, in_i)` row-major (PyTorch's
//! layout) followed by `b_i` `(H)`; [`pack_parameters`] builds that from the layers, and
//! Candle's `cat` backward hands each slice of the gradient back to its parameter.

use std::sync::Mutex;

use candle_core::{Shape, Tensor};
use candle_nn::Linear;
use rayon::prelude::*;

use crate::kernels::bias::bias_add;
use crate::kernels::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use crate::kernels::gemm::gemm_f32;
use crate::kernels::use_fused;

const ROWS_PER_TASK: usize = 256;

/// Sizes of the trunk.
#[derive(Debug, Clone, PartialEq)]
pub struct TrunkShape {
    /// Width of the input embedding `x`.
    pub input_dim: usize,
    /// Width of every layer.
    pub hidden: usize,
    /// Whether layer `i` takes `[y, x]` (true) or `y` alone; layer 0 takes `x`.
    pub skip: Vec<bool>,
}

impl TrunkShape {
    /// Input width of layer `i`.
    pub fn in_dim(&self, i: usize) -> usize {
        if i == 0 {
            self.input_dim
        } else if self.skip[i] {
            self.hidden + self.input_dim
        } else {
            self.hidden
        }
    }

    /// Offset of layer `i`'s weight in the packed parameters.
    fn offset(&self, i: usize) -> usize {
        (0..i).map(|j| self.hidden * (self.in_dim(j) + 1)).sum()
    }

    /// Number of packed parameters.
    pub fn n_parameters(&self) -> usize {
        self.offset(self.skip.len())
    }
}

/// The layers' weights and biases flattened in the packed order: `(P)` with
/// `P = Σ_i H·(in_i + 1)`. Differentiable (a `cat`).
pub fn pack_parameters(layers: &[Linear]) -> candle_core::Result<Tensor> {
    let mut parts = Vec::with_capacity(2 * layers.len());
    for l in layers {
        parts.push(l.weight().flatten_all()?);
        let bias = match l.bias() {
            Some(b) => b.clone(),
            None => Tensor::zeros(l.weight().dim(0)?, l.weight().dtype(), l.weight().device())?,
        };
        parts.push(bias);
    }
    Tensor::cat(&parts, 0)
}

/// The trunk's output `(M, H)` for the embedding `x` `(M, input_dim)`: the fused [`trunk`] where
/// [`use_fused`] allows, else [`trunk_tensor_ops`]; the twin also when autograd tracks `x`
/// (points of rays being trained, camera refinement), since the fused backward pass gives
/// the parameters their gradient but not the input.
pub fn trunk_forward(
    x: &Tensor,
    layers: &[Linear],
    shape: &TrunkShape,
) -> candle_core::Result<Tensor> {
    if use_fused(x) && !crate::kernels::needs_grad(x) {
        return trunk(x, &pack_parameters(layers)?, shape);
    }
    trunk_tensor_ops(x, layers, shape)
}

/// The trunk as Candle ops (any device and dtype, differentiable): `relu(y·Wᵀ + b)` per layer,
/// with `y = [y, x]` before the skip layers.
///
/// `x`: `(M, input_dim)`; returns `(M, H)`.
pub fn trunk_tensor_ops(
    x: &Tensor,
    layers: &[Linear],
    shape: &TrunkShape,
) -> candle_core::Result<Tensor> {
    let mut y = x.clone();
    for (i, layer) in layers.iter().enumerate() {
        if i > 0 && shape.skip[i] {
            y = Tensor::cat(&[&y, x], 1)?;
        }
        y = y.matmul(&layer.weight().t()?)?;
        if let Some(b) = layer.bias() {
            y = bias_add(&y, b)?;
        }
        y = y.relu()?;
    }
    Ok(y)
}

/// The trunk's output `(M, H)` for the embedding `x` `(M, input_dim)` and the packed
/// parameters (CPU, f32). Keeps activations for the backward pass only when the parameters
/// track gradients.
pub fn trunk(x: &Tensor, params: &Tensor, shape: &TrunkShape) -> candle_core::Result<Tensor> {
    let keep = params.track_op();
    let op = Fused(FusedTrunk {
        shape: shape.clone(),
        saved: Mutex::new(None),
        keep,
    });
    let x = x.contiguous()?;
    let params = params.contiguous()?;
    if keep {
        x.apply_op2(&params, op)
    } else {
        x.apply_op2_no_bwd(&params, &op)
    }
}

struct FusedTrunk {
    shape: TrunkShape,
    /// Every layer's output, kept by the forward pass for the backward pass.
    saved: Mutex<Option<Vec<Vec<f32>>>>,
    keep: bool,
}

impl FusedTrunk {
    /// Forward pass: every layer's output, `(M, H)` each.
    fn layers(&self, x: &[f32], params: &[f32], m: usize) -> Vec<Vec<f32>> {
        let s = &self.shape;
        let h = s.hidden;
        let mut outputs: Vec<Vec<f32>> = Vec::with_capacity(s.skip.len());
        for i in 0..s.skip.len() {
            let in_i = s.in_dim(i);
            let w = &params[s.offset(i)..s.offset(i) + h * in_i];
            let b = &params[s.offset(i) + h * in_i..s.offset(i) + h * (in_i + 1)];
            let mut out = vec![0f32; m * h];
            // The hidden part of the input (the previous output), or x for layer 0.
            let (y, y_dim) = match outputs.last() {
                Some(prev) => (prev.as_slice(), h),
                None => (x, s.input_dim),
            };
            // out = y · W[:, :y_dim]ᵀ: rhs(k, n) = W[n][k].
            gemm_f32(
                (m, h, y_dim),
                &mut out,
                h,
                false,
                y,
                (y_dim, 1),
                w,
                (1, in_i),
                true,
            );
            if i > 0 && s.skip[i] {
                // + x · W[:, h:]ᵀ.
                gemm_f32(
                    (m, h, s.input_dim),
                    &mut out,
                    h,
                    true,
                    x,
                    (s.input_dim, 1),
                    &w[h..],
                    (1, in_i),
                    true,
                );
            }
            out.par_chunks_mut(ROWS_PER_TASK * h).for_each(|rows| {
                for row in rows.chunks_exact_mut(h) {
                    for (v, b) in row.iter_mut().zip(b) {
                        *v = (*v + b).max(0.0);
                    }
                }
            });
            outputs.push(out);
        }
        outputs
    }
}

impl CpuKernel<2> for FusedTrunk {
    const NAME: &'static str = "nerf-trunk";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [x, params] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let (m, d) = inputs[0].shape().dims2()?;
        let s = &self.shape;
        if d != s.input_dim || params.len() != s.n_parameters() || s.skip.is_empty() {
            candle_core::bail!(
                "nerf-trunk: input width {d} (expected {}), {} parameters (expected {})",
                s.input_dim,
                params.len(),
                s.n_parameters()
            );
        }
        let mut outputs = self.layers(x, params, m);
        let result = if self.keep {
            let last = outputs.last().expect("at least one layer").clone();
            *self.saved.lock().expect("trunk lock") = Some(outputs);
            last
        } else {
            outputs.pop().expect("at least one layer")
        };
        Ok((result, Shape::from((m, s.hidden))))
    }

    fn gradients(&self, [x, params]: [&Tensor; 2], grad: &Tensor) -> KernelGradients<2> {
        let s = &self.shape;
        let h = s.hidden;
        let (m, _) = x.dims2()?;
        let xs = x.flatten_all()?.to_vec1::<f32>()?;
        let ps = params.flatten_all()?.to_vec1::<f32>()?;
        let saved = self.saved.lock().expect("trunk lock").take();
        let outputs = match saved {
            Some(o) => o,
            None => self.layers(&xs, &ps, m),
        };
        let mut g = grad.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
        let mut dparams = vec![0f32; s.n_parameters()];
        // The next layer's gradient is written over the buffer of the gradient before it
        // (the two swap each layer): one `(M, H)` allocation for the whole pass, not one a
        // layer.
        let mut spare: Vec<f32> = Vec::new();
        for i in (0..s.skip.len()).rev() {
            let in_i = s.in_dim(i);
            let off = s.offset(i);
            let (dw, rest) = dparams[off..].split_at_mut(h * in_i);
            relu_backward(&mut g, &outputs[i], &mut rest[..h]);
            let (y, y_dim) = if i == 0 {
                (xs.as_slice(), s.input_dim)
            } else {
                (outputs[i - 1].as_slice(), h)
            };
            // dW[:, :y_dim] = Gᵀ · y: lhs(h_out, m) = G[m][h_out], rhs(m, k) = y[m][k].
            gemm_f32(
                (h, y_dim, m),
                dw,
                in_i,
                false,
                &g,
                (1, h),
                y,
                (y_dim, 1),
                true,
            );
            if i > 0 && s.skip[i] {
                gemm_f32(
                    (h, s.input_dim, m),
                    &mut dw[h..],
                    in_i,
                    false,
                    &g,
                    (1, h),
                    &xs,
                    (s.input_dim, 1),
                    true,
                );
            }
            if i > 0 {
                // G_{i-1} = G · W[:, :h]: rhs(k = h_out, n) = W[h_out][n].
                let w = &ps[off..off + h * in_i];
                spare.resize(m * h, 0.0);
                gemm_f32(
                    (m, h, h),
                    &mut spare,
                    h,
                    false,
                    &g,
                    (h, 1),
                    w,
                    (in_i, 1),
                    true,
                );
                std::mem::swap(&mut g, &mut spare);
            }
        }
        let dparams = Tensor::from_vec(dparams, s.n_parameters(), params.device())?;
        Ok([None, Some(dparams)])
    }
}

/// Through a ReLU layer's activation: `g` `(M, H)` becomes `g ⊙ [y > 0]` for the layer's
/// outputs `y` `(M, H)`, and its column sums (the bias gradient) are added to `db` `(H)`, in
/// one parallel pass.
fn relu_backward(g: &mut [f32], y: &[f32], db: &mut [f32]) {
    let h = db.len();
    let partial_sums: Vec<Vec<f32>> = g
        .par_chunks_mut(ROWS_PER_TASK * h)
        .zip(y.par_chunks(ROWS_PER_TASK * h))
        .map(|(g, y)| {
            let mut acc = vec![0f32; h];
            for (g, y) in g.chunks_exact_mut(h).zip(y.chunks_exact(h)) {
                // Branch-free so that it vectorises (the mask is data-dependent).
                for ((g, y), a) in g.iter_mut().zip(y).zip(acc.iter_mut()) {
                    let masked = if *y > 0.0 { *g } else { 0.0 };
                    *g = masked;
                    *a += masked;
                }
            }
            acc
        })
        .collect();
    for part in &partial_sums {
        for (d, v) in db.iter_mut().zip(part) {
            *d += v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::compare::assert_close;
    use crate::kernels::test_support::weighted_sum_gradients;
    use candle_core::{Device, Var};
    use candle_nn::Module;

    /// The same trunk through Candle ops.
    fn reference(x: &Tensor, layers: &[Linear], shape: &TrunkShape) -> Tensor {
        let mut y = x.clone();
        for (i, l) in layers.iter().enumerate() {
            if i > 0 && shape.skip[i] {
                y = Tensor::cat(&[&y, x], 1).unwrap();
            }
            y = l.forward(&y).unwrap().relu().unwrap();
        }
        y
    }

    #[test]
    fn forward_and_gradients_match_candle_autodiff() {
        let dev = Device::Cpu;
        let shape = TrunkShape {
            input_dim: 7,
            hidden: 12,
            skip: vec![false, false, true, false],
        };
        let m = 300;
        let x = Tensor::randn(0f32, 1.0, (m, 7), &dev).unwrap();
        let vars: Vec<(Var, Var)> = (0..4)
            .map(|i| {
                let w = Var::randn(0f32, 0.4, (12, shape.in_dim(i)), &dev).unwrap();
                let b = Var::randn(0.05f32, 0.1, 12, &dev).unwrap();
                (w, b)
            })
            .collect();
        let layers: Vec<Linear> = vars
            .iter()
            .map(|(w, b)| Linear::new(w.as_tensor().clone(), Some(b.as_tensor().clone())))
            .collect();
        let weight = Tensor::randn(0f32, 1.0, (m, 12), &dev).unwrap();
        let slow = reference(&x, &layers, &shape);
        let fast = trunk(&x, &pack_parameters(&layers).unwrap(), &shape).unwrap();
        let diff = |a: &Tensor, b: &Tensor| crate::core::compare::max_abs_difference(a, b).unwrap();
        assert!(diff(&slow, &fast) < 1e-5, "forward {}", diff(&slow, &fast));
        let g_slow = weighted_sum_gradients(&slow, &weight);
        let g_fast = weighted_sum_gradients(&fast, &weight);
        for (i, (w, b)) in vars.iter().enumerate() {
            for v in [w, b] {
                let (a, c) = (g_slow.get(v).unwrap(), g_fast.get(v).unwrap());
                assert_close(c, a, 1e-5, &format!("layer {i}"));
            }
        }
        // Without gradient tracking nothing is kept and the output is the same.
        let detached: Vec<Linear> = layers
            .iter()
            .map(|l| Linear::new(l.weight().detach(), l.bias().map(|b| b.detach())))
            .collect();
        let plain = trunk(&x, &pack_parameters(&detached).unwrap(), &shape).unwrap();
        assert!(diff(&plain, &fast) == 0.0);
    }
}
