//! The NGP field's two small MLPs (`nerf::field::ngp`) as one fused CPU op with a
//! hand-written backward pass.
//!
//! Through Candle ops, each of the MLPs' dozen steps (matmul, bias, ReLU, narrow, the per-ray
//! add, sigmoid) reads and writes an `(M, 64)` buffer: about 50 MB each at the ~200k samples of
//! a training step, and the backward pass allocates a zeroed buffer per activation and adds
//! into it. Here each task takes 256 samples through every layer while they sit in cache
//! (`gemm` on the calling thread), and the backward pass recomputes them the same way and
//! accumulates the weight gradients per thread.
//!
//! For samples `i` with encoding `e_i` and ray `r(i)`:
//!
//! * `h0 = relu(W0·e + b0)`, `o1 = W1·h0 + b1` (`1 + G` values: the raw density, then `G`
//!   geometry features `g`);
//! * `h1 = relu(Wg·g + p_{r(i)})` where `p` `(N, H)` is the per-ray part of the colour MLP's
//!   first layer (its direction weights times the direction encoding, plus its bias);
//! * `h2 = relu(W2·h1 + b2)`, `rgb = sigmoid(W3·h2 + b3)`.
//!
//! The output is `(M, 4)`: `[raw density, r, g, b]`. Parameters are passed packed (see
//! [`MlpShape`]); the tensor-op twin is `ngp_mlp_tensor_ops`.

use candle_core::{Shape, Tensor};
use rayon::prelude::*;

use nerf_kernels::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use nerf_kernels::gemm::gemm_f32;
use nerf_kernels::mlp_block::{
    add_by_ray, add_per_ray_relu, as_is, check_rays, linear, mask, recycle, relu, rgb_head,
    rgb_head_backward, task_buffer, times, transposed, weight_grad, GradientSums, BLOCKS_PER_SUM,
    ROWS_PER_TASK,
};
use nerf_kernels::storage::host_values;

/// Widths of the two MLPs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MlpShape {
    /// Encoding width `E` (`L·F`).
    pub enc: usize,
    /// Hidden width `H` of every layer.
    pub hidden: usize,
    /// Geometry features `G` passed from the density MLP to the colour MLP.
    pub geo: usize,
}

/// Offsets of the packed parameters, in order: `W0 (H, E)`, `b0 (H)`, `W1 (1+G, H)`,
/// `b1 (1+G)`, `Wg (H, G)`, `W2 (H, H)`, `b2 (H)`, `W3 (3, H)`, `b3 (3)`; weights row-major
/// `(out, in)` as PyTorch's `nn.Linear`.
#[derive(Debug, Clone, Copy)]
struct Offsets {
    w0: usize,
    b0: usize,
    w1: usize,
    b1: usize,
    wg: usize,
    w2: usize,
    b2: usize,
    w3: usize,
    end: usize,
}

impl MlpShape {
    /// (encoding width E, hidden width H, geometry features G).
    fn dims(&self) -> (usize, usize, usize) {
        (self.enc, self.hidden, self.geo)
    }

    fn offsets(&self) -> Offsets {
        let (e, h, o) = (self.enc, self.hidden, 1 + self.geo);
        let w0 = 0;
        let b0 = w0 + h * e;
        let w1 = b0 + h;
        let b1 = w1 + o * h;
        let wg = b1 + o;
        let w2 = wg + h * self.geo;
        let b2 = w2 + h * h;
        let w3 = b2 + h;
        let b3 = w3 + 3 * h;
        Offsets {
            w0,
            b0,
            w1,
            b1,
            wg,
            w2,
            b2,
            w3,
            end: b3 + 3,
        }
    }

    /// Number of packed parameters.
    pub(crate) fn n_parameters(&self) -> usize {
        self.offsets().end
    }

    /// Where each layer's parameters lie in the packed order: `W0, b0, W1, b1, Wg, W2, b2,
    /// W3, b3`.
    pub fn ranges(&self) -> [std::ops::Range<usize>; 9] {
        let o = self.offsets();
        let b3 = o.w3 + 3 * self.hidden;
        [
            o.w0..o.b0,
            o.b0..o.w1,
            o.w1..o.b1,
            o.b1..o.wg,
            o.wg..o.w2,
            o.w2..o.b2,
            o.b2..o.w3,
            o.w3..b3,
            b3..o.end,
        ]
    }
}

/// The layers' parameters flattened in the packed order of [`MlpShape`]: `(P)`.
/// Differentiable (a `cat`). `wg` is the geometry columns of the colour MLP's first weight.
pub fn pack_parameters(
    w0: &Tensor,
    b0: &Tensor,
    w1: &Tensor,
    b1: &Tensor,
    wg: &Tensor,
    [w2, b2, w3, b3]: [&Tensor; 4],
) -> candle_core::Result<Tensor> {
    let parts = [w0, b0, w1, b1, wg, w2, b2, w3, b3]
        .iter()
        .map(|t| t.flatten_all())
        .collect::<candle_core::Result<Vec<_>>>()?;
    Tensor::cat(&parts, 0)
}

/// The fused MLPs: `enc` `(M, E)`, `per_ray` `(N, H)`, `ray_index` (the ray of each sample,
/// `M` entries below `N`), packed `params` `(P)`, all f32 on the CPU; returns `(M, 4)`
/// (`[raw density, r, g, b]`). Gradients flow to `enc`, `per_ray` and `params`.
pub(crate) fn ngp_mlp(
    enc: &Tensor,
    per_ray: &Tensor,
    ray_index: &[u32],
    params: &Tensor,
    shape: MlpShape,
) -> candle_core::Result<Tensor> {
    let (m, e) = enc.dims2()?;
    let (n, h) = per_ray.dims2()?;
    if e != shape.enc || h != shape.hidden {
        let (x, p) = (enc.dims(), per_ray.dims());
        candle_core::bail!("ngp-mlp: encoding {x:?}, per-ray {p:?} for shape {shape:?}");
    }
    check_rays("ngp-mlp", ray_index, m, n)?;
    let op = Fused(NgpMlp {
        shape,
        rays: ray_index.to_vec(),
    });
    let (enc, per_ray, params) = (
        enc.contiguous()?,
        per_ray.contiguous()?,
        params.contiguous()?,
    );
    if enc.track_op() || per_ray.track_op() || params.track_op() {
        enc.apply_op3(&per_ray, &params, op)
    } else {
        enc.apply_op3_no_bwd(&per_ray, &params, &op)
    }
}

/// The NGP MLPs on `enc` `(M, E)` and `per_ray` `(N, H)`: the fused `ngp_mlp` where
/// [`nerf_kernels::use_fused`] allows (f32 on the CPU, fused kernels chosen), else its twin
/// `ngp_mlp_tensor_ops`. `ray_index`: each sample's ray, as a `(M,)` u32 tensor on the
/// inputs' device and as the same values on the host. Returns `(M, 4)`.
pub fn mlp_forward(
    enc: &Tensor,
    per_ray: &Tensor,
    (ray_index, rays): (&Tensor, &[u32]),
    layers: &MlpLayers,
) -> candle_core::Result<Tensor> {
    if nerf_kernels::use_fused(enc) {
        let l = layers;
        let packed = pack_parameters(l.w0, l.b0, l.w1, l.b1, l.wg, [l.w2, l.b2, l.w3, l.b3])?;
        let shape = MlpShape {
            enc: enc.dim(1)?,
            hidden: l.w0.dim(0)?,
            geo: l.wg.dim(1)?,
        };
        return ngp_mlp(enc, per_ray, rays, &packed, shape);
    }
    ngp_mlp_tensor_ops(enc, per_ray, ray_index, layers)
}

/// The tensor-op twin of [`ngp_mlp`] (any device and dtype): the same layers through Candle
/// ops, `ray_index` `(M,)` u32 on the tensors' device.
pub(crate) fn ngp_mlp_tensor_ops(
    enc: &Tensor,
    per_ray: &Tensor,
    ray_index: &Tensor,
    layers: &MlpLayers,
) -> candle_core::Result<Tensor> {
    let lin = |x: &Tensor, w: &Tensor, b: Option<&Tensor>| -> candle_core::Result<Tensor> {
        let y = x.matmul(&w.t()?)?;
        match b {
            Some(b) => y.broadcast_add(b),
            None => Ok(y),
        }
    };
    let h0 = lin(enc, layers.w0, Some(layers.b0))?.relu()?;
    let o1 = lin(&h0, layers.w1, Some(layers.b1))?;
    let geo = o1.narrow(1, 1, o1.dim(1)? - 1)?;
    let h1 = lin(&geo, layers.wg, None)?
        .add(&per_ray.index_select(ray_index, 0)?)?
        .relu()?;
    let h2 = lin(&h1, layers.w2, Some(layers.b2))?.relu()?;
    let rgb = candle_nn::ops::sigmoid(&lin(&h2, layers.w3, Some(layers.b3))?)?;
    Tensor::cat(&[&o1.narrow(1, 0, 1)?, &rgb], 1)
}

/// The MLPs' parameters as separate tensors, for `ngp_mlp_tensor_ops`.
pub struct MlpLayers<'a> {
    /// Density layer 0 weight `(H, E)`.
    pub w0: &'a Tensor,
    /// Density layer 0 bias `(H)`.
    pub b0: &'a Tensor,
    /// Density layer 1 weight `(1+G, H)`.
    pub w1: &'a Tensor,
    /// Density layer 1 bias `(1+G)`.
    pub b1: &'a Tensor,
    /// Colour layer 0's geometry columns `(H, G)`.
    pub wg: &'a Tensor,
    /// Colour layer 1 weight `(H, H)`.
    pub w2: &'a Tensor,
    /// Colour layer 1 bias `(H)`.
    pub b2: &'a Tensor,
    /// Colour layer 2 weight `(3, H)`.
    pub w3: &'a Tensor,
    /// Colour layer 2 bias `(3)`.
    pub b3: &'a Tensor,
}

struct NgpMlp {
    shape: MlpShape,
    rays: Vec<u32>,
}

/// One task's activations, `c` rows each.
struct Activations {
    h0: Vec<f32>,
    o1: Vec<f32>,
    h1: Vec<f32>,
    h2: Vec<f32>,
    rgb: Vec<f32>,
}

impl Activations {
    /// Hands the buffers back for reuse ([`recycle`]).
    fn recycle(self) {
        recycle([self.h0, self.o1, self.h1, self.h2, self.rgb]);
    }
}

impl NgpMlp {
    /// The forward pass of `c = enc.len() / E` samples whose rays are `rays`.
    fn forward(&self, enc: &[f32], rays: &[u32], per_ray: &[f32], p: &[f32]) -> Activations {
        let (e, h, g) = self.shape.dims();
        let o = self.shape.offsets();
        let c = rays.len();
        let mut a = Activations {
            h0: task_buffer(c * h),
            o1: task_buffer(c * (1 + g)),
            h1: task_buffer(c * h),
            h2: task_buffer(c * h),
            rgb: Vec::new(),
        };
        linear(&mut a.h0, enc, (c, e, h), &p[o.w0..o.b0], &p[o.b0..o.w1]);
        relu(&mut a.h0);
        linear(
            &mut a.o1,
            &a.h0,
            (c, h, 1 + g),
            &p[o.w1..o.b1],
            &p[o.b1..o.wg],
        );
        // h1 = Wg·geo + p_ray: geo is o1 from column 1, row stride 1 + G.
        let wg = transposed(&p[o.wg..o.w2], g);
        times(&mut a.h1, false, (&a.o1[1..], 1 + g), wg, (c, g, h));
        add_per_ray_relu(&mut a.h1, rays, per_ray);
        linear(&mut a.h2, &a.h1, (c, h, h), &p[o.w2..o.b2], &p[o.b2..o.w3]);
        relu(&mut a.h2);
        a.rgb = rgb_head(&a.h2, &p[o.w3..o.end]);
        a
    }
}

impl NgpMlp {
    /// The backward pass of one task's samples: their encoding gradient into `d_enc`, the
    /// parameter and per-ray gradients added into `sums`.
    #[allow(clippy::too_many_arguments)]
    fn backward(
        &self,
        enc: &[f32],
        rays: &[u32],
        grad: &[f32],
        per_ray: &[f32],
        p: &[f32],
        d_enc: &mut [f32],
        sums: &mut GradientSums,
    ) {
        let (e, h, g) = self.shape.dims();
        let o = self.shape.offsets();
        let c = rays.len();
        let a = self.forward(enc, rays, per_ray, p);
        let dp = &mut sums.params;
        // Colour head: the sigmoid and output layer, then the two ReLU layers.
        let d_c1 = rgb_head_backward(
            (grad, &a.rgb, &a.h2),
            (&p[o.w3..o.end], &mut dp[o.w3..o.end]),
        );
        let (dw2, db2) = dp[o.w2..o.w3].split_at_mut(h * h);
        weight_grad((dw2, h), Some(db2), &d_c1, (&a.h1, h), (c, h, h));
        let mut d_c0 = task_buffer(c * h);
        times(
            &mut d_c0,
            false,
            (&d_c1, h),
            as_is(&p[o.w2..o.b2], h),
            (c, h, h),
        );
        mask(&mut d_c0, &a.h1);
        weight_grad(
            (&mut dp[o.wg..o.w2], g),
            None,
            &d_c0,
            (&a.o1[1..], 1 + g),
            (c, h, g),
        );
        add_by_ray(&mut sums.per_ray, &d_c0, rays);
        // Density MLP: the raw density's gradient and the geometry features'.
        let mut d_o1 = task_buffer(c * (1 + g));
        for (i, row) in d_o1.chunks_exact_mut(1 + g).enumerate() {
            row[0] = grad[4 * i];
        }
        gemm_f32(
            (c, g, h),
            &mut d_o1[1..],
            1 + g,
            false,
            &d_c0,
            (h, 1),
            &p[o.wg..o.w2],
            (g, 1),
            false,
        );
        let (dw1, db1) = dp[o.w1..o.wg].split_at_mut((1 + g) * h);
        weight_grad((dw1, h), Some(db1), &d_o1, (&a.h0, h), (c, 1 + g, h));
        let mut d_a0 = task_buffer(c * h);
        times(
            &mut d_a0,
            false,
            (&d_o1, 1 + g),
            as_is(&p[o.w1..o.b1], h),
            (c, 1 + g, h),
        );
        mask(&mut d_a0, &a.h0);
        let (dw0, db0) = dp[o.w0..o.w1].split_at_mut(h * e);
        weight_grad((dw0, e), Some(db0), &d_a0, (enc, e), (c, h, e));
        times(
            d_enc,
            false,
            (&d_a0, h),
            as_is(&p[o.w0..o.b0], e),
            (c, h, e),
        );
        recycle([d_c1, d_c0, d_o1, d_a0]);
        a.recycle();
    }
}

impl CpuKernel<3> for NgpMlp {
    const NAME: &'static str = "ngp-mlp";

    fn cpu_forward(&self, inputs: [CpuInput; 3]) -> KernelOutput {
        let [enc, per_ray, params] = CpuInput::all_f32(&inputs, Self::NAME)?;
        if params.len() != self.shape.n_parameters() {
            candle_core::bail!(
                "ngp-mlp: {} parameters, expected {}",
                params.len(),
                self.shape.n_parameters()
            );
        }
        let out = mlp_values(self.shape, enc, (&self.rays, per_ray), params);
        Ok((out, Shape::from((self.rays.len(), 4))))
    }

    fn gradients(&self, [enc, per_ray, params]: [&Tensor; 3], grad: &Tensor) -> KernelGradients<3> {
        let [enc_v, per_ray_v, p, g] = host_values([enc, per_ray, params, grad])?;
        let (d_enc, sums) = mlp_gradients(self.shape, &enc_v, (&self.rays, &per_ray_v), &p, &g);
        let dev = enc.device();
        Ok([
            Some(Tensor::from_vec(d_enc, enc.shape(), dev)?),
            Some(Tensor::from_vec(sums.per_ray, per_ray.shape(), dev)?),
            Some(Tensor::from_vec(
                sums.params,
                self.shape.n_parameters(),
                dev,
            )?),
        ])
    }
}

/// The fused MLPs' forward pass on host values: `(M, 4)` `[raw density, r, g, b]` from the
/// encoding `enc` `(M, E)`, each sample's ray `rays` `(M)` into `per_ray` `(N, H)`, and the
/// packed `params` `(P)` ([`MlpShape`]). What `ngp_mlp` computes, without a tensor.
pub fn mlp_values(
    shape: MlpShape,
    enc: &[f32],
    (rays, per_ray): (&[u32], &[f32]),
    params: &[f32],
) -> Vec<f32> {
    let mlp = NgpMlp {
        shape,
        rays: Vec::new(),
    };
    let (e, g1) = (shape.enc, 1 + shape.geo);
    let mut out = vec![0f32; rays.len() * 4];
    out.par_chunks_mut(ROWS_PER_TASK * 4)
        .zip(enc.par_chunks(ROWS_PER_TASK * e))
        .zip(rays.par_chunks(ROWS_PER_TASK))
        .for_each(|((out, enc), rays)| {
            let a = mlp.forward(enc, rays, per_ray, params);
            for (i, row) in out.chunks_exact_mut(4).enumerate() {
                row[0] = a.o1[i * g1];
                row[1..].copy_from_slice(&a.rgb[3 * i..3 * i + 3]);
            }
            a.recycle();
        });
    out
}

/// The raw density alone (the density MLP's first output) of the encoding `enc` `(M, E)`:
/// `(M)`, the value [`mlp_values`] gives in its column 0, without the colour MLP (what the
/// occupancy grid probes). Tasks of 256 samples through both layers while they sit in cache.
pub fn raw_density_values(shape: MlpShape, enc: &[f32], params: &[f32]) -> Vec<f32> {
    let (e, h) = (shape.enc, shape.hidden);
    let o = shape.offsets();
    let (w1, b1) = (&params[o.w1..o.w1 + h], params[o.b1]);
    let mut out = vec![0f32; enc.len() / e];
    out.par_chunks_mut(ROWS_PER_TASK)
        .zip(enc.par_chunks(ROWS_PER_TASK * e))
        .for_each(|(out, enc)| {
            let c = out.len();
            let mut h0 = task_buffer(c * h);
            linear(
                &mut h0,
                enc,
                (c, e, h),
                &params[o.w0..o.b0],
                &params[o.b0..o.w1],
            );
            relu(&mut h0);
            // Row 0 of W1 and b1[0], as the full layer's first column (the same sum order as
            // `gemm` takes for one output column is not promised: equal to rounding).
            for (v, row) in out.iter_mut().zip(h0.chunks_exact(h)) {
                *v = row.iter().zip(w1).map(|(x, w)| x * w).sum::<f32>() + b1;
            }
            recycle([h0]);
        });
    out
}

/// The fused MLPs' backward pass on host values, for the output gradient `grad` `(M, 4)` of
/// [`mlp_values`] on the same inputs: the encoding's gradient `(M, E)`, and the packed
/// parameters' `(P)` and per-ray inputs' `(N, H)` gradients. Fixed blocks of samples are
/// summed in order (see `mlp_block`), so the sums do not depend on the thread count.
pub fn mlp_gradients(
    shape: MlpShape,
    enc: &[f32],
    (rays, per_ray): (&[u32], &[f32]),
    params: &[f32],
    grad: &[f32],
) -> (Vec<f32>, GradientSums) {
    let mlp = NgpMlp {
        shape,
        rays: Vec::new(),
    };
    let e = shape.enc;
    let n_params = shape.n_parameters();
    let mut d_enc = vec![0f32; enc.len()];
    let block = ROWS_PER_TASK * BLOCKS_PER_SUM;
    let partial: Vec<GradientSums> = d_enc
        .par_chunks_mut(block * e)
        .zip(enc.par_chunks(block * e))
        .zip(rays.par_chunks(block))
        .zip(grad.par_chunks(block * 4))
        .map(|(((d_enc, enc), rays), g)| {
            // The block's rays only: indices re-based to the first, per-ray rows sliced.
            let h = shape.hidden;
            let first = rays.iter().copied().min().unwrap_or(0) as usize;
            let last = rays.iter().copied().max().map_or(first, |r| r as usize + 1);
            let local: Vec<u32> = rays.iter().map(|&r| r - first as u32).collect();
            let window = &per_ray[first * h..last * h];
            let mut sums = GradientSums::zeros_from(n_params, first * h, window.len());
            for (((d_enc, enc), rays), g) in d_enc
                .chunks_mut(ROWS_PER_TASK * e)
                .zip(enc.chunks(ROWS_PER_TASK * e))
                .zip(local.chunks(ROWS_PER_TASK))
                .zip(g.chunks(ROWS_PER_TASK * 4))
            {
                mlp.backward(enc, rays, g, window, params, d_enc, &mut sums);
            }
            sums
        })
        .collect();
    (
        d_enc,
        GradientSums::add_in_order(partial, n_params, per_ray.len()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use nerf_core::compare::assert_close;
    use nerf_kernels::test_support::weighted_sum_gradients;

    #[test]
    fn fused_matches_tensor_ops_forward_and_backward() {
        let dev = Device::Cpu;
        let shape = MlpShape {
            enc: 6,
            hidden: 8,
            geo: 3,
        };
        let var = |dims: &[usize], s: f64| Var::randn(0f32, s as f32, dims, &dev).unwrap();
        let (h, g, e) = (shape.hidden, shape.geo, shape.enc);
        let w0 = var(&[h, e], 0.5);
        let b0 = var(&[h], 0.2);
        let w1 = var(&[1 + g, h], 0.5);
        let b1 = var(&[1 + g], 0.2);
        let wg = var(&[h, g], 0.5);
        let w2 = var(&[h, h], 0.5);
        let b2 = var(&[h], 0.2);
        let w3 = var(&[3, h], 0.5);
        let b3 = var(&[3], 0.2);
        // 600 samples of 7 rays (more than two tasks, a ray split across tasks, one ray with
        // no sample, and one out of order).
        let m = 600;
        let mut rays: Vec<u32> = (0..m as u32).map(|i| (i * 7 / m as u32).min(5)).collect();
        rays[10] = 6;
        let enc = var(&[m, e], 1.0);
        let per_ray = var(&[7, h], 0.5);
        let weight = Tensor::randn(0f32, 1.0, (m, 4), &dev).unwrap();
        let all = [&w0, &b0, &w1, &b1, &wg, &w2, &b2, &w3, &b3, &enc, &per_ray];
        let packed =
            pack_parameters(&w0, &b0, &w1, &b1, &wg, [w2.as_tensor(), &b2, &w3, &b3]).unwrap();
        let fast = ngp_mlp(&enc, &per_ray, &rays, &packed, shape).unwrap();
        let layers = MlpLayers {
            w0: &w0,
            b0: &b0,
            w1: &w1,
            b1: &b1,
            wg: &wg,
            w2: &w2,
            b2: &b2,
            w3: &w3,
            b3: &b3,
        };
        let idx = Tensor::new(rays.as_slice(), &dev).unwrap();
        let slow = ngp_mlp_tensor_ops(&enc, &per_ray, &idx, &layers).unwrap();
        let diff = |a: &Tensor, b: &Tensor| nerf_core::compare::max_abs_difference(a, b).unwrap();
        assert!(diff(&fast, &slow) < 1e-5, "forward {}", diff(&fast, &slow));
        let gf = weighted_sum_gradients(&fast, &weight);
        let gs = weighted_sum_gradients(&slow, &weight);
        for v in all {
            let (a, b) = (gf.get(v).unwrap(), gs.get(v).unwrap());
            assert_close(a, b, 1e-5, &format!("gradient {:?}", v.dims()));
        }
    }
}
