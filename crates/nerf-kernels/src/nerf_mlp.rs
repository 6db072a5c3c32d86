//! The NeRF MLP (`nerf::field::nerf`: the `mlp_xyz` trunk with its skip layers, the density
//! layer, the intermediate layer and the colour head) as one fused CPU op with a hand-written
//! backward pass.
//!
//! Through Candle ops, every layer reads and writes an `(M, H)` buffer (64 MB at the 131 072
//! samples of the homework's training step), and the backward pass starts every gradient as a
//! zeroed buffer and adds into it. Here each task takes 256 samples through every layer while
//! they sit in cache (`gemm` on the calling thread, a skip layer as two products
//! `[y, x]·Wᵀ = y·W_yᵀ + x·W_xᵀ` with no concatenation). When the op is to be differentiated, the
//! forward pass keeps each task's activations; the backward pass walks each task back through
//! them and adds its weight gradients into per-block sums, added in block order
//! (`mlp_block.rs`). The tasks' buffers are reused from op to op, not allocated zeroed.
//!
//! For samples `i` with embedding `x_i` and ray `r(i)`:
//!
//! * `y_0 = relu(W_0·x + b_0)`, `y_l = relu(W_l·y_{l−1} + b_l)` or, at a skip layer,
//!   `relu(W_l·[y_{l−1}, x] + b_l)`; `y` is the last layer's output;
//! * raw density `W_σ·y + b_σ` (the caller adds the training noise and the ReLU);
//! * `f = W_f·y + b_f` (the intermediate layer), `h = relu(W_c·f + p_{r(i)})` where `p` `(N, D)`
//!   is the per-ray part of the colour layer (its direction columns times the direction
//!   embedding, plus its bias), `rgb = sigmoid(W_o·h + b_o)`.
//!
//! The output is `(M, 4)`, `[raw density, r, g, b]`, or `(M, 1)` for the density alone (the
//! occupancy grid's queries: no colour head, no backward pass). Parameters are packed (see
//! [`NerfMlpShape`]); the tensor-op twin is `nerf_mlp_tensor_ops`.

use std::sync::Mutex;

use candle_core::{Shape, Tensor};
use candle_nn::Linear;
use rayon::prelude::*;

use crate::bias::bias_add;
use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use crate::mlp_block::{
    add_bias, add_by_ray, add_per_ray_relu, as_is, check_rays, linear, mask, recycle, relu,
    rgb_head, rgb_head_backward, task_buffer, times, transposed, weight_grad, GradientSums,
    BLOCKS_PER_SUM, ROWS_PER_TASK,
};
use crate::storage::host_values;
use crate::use_fused;

/// Sizes of the trunk (`mlp_xyz`).
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
    pub(crate) fn in_dim(&self, i: usize) -> usize {
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

    /// Number of packed trunk parameters.
    fn n_parameters(&self) -> usize {
        self.offset(self.skip.len())
    }
}

/// Sizes of the whole MLP. Packed parameters, in order: each trunk layer's `W_l (H, in_l)` and
/// `b_l (H)`, then `W_σ (1, H)`, `b_σ (1)`, `W_f (H, H)`, `b_f (H)`, `W_c (D, H)` (the colour
/// layer's feature columns), `W_o (3, D)`, `b_o (3)`; weights row-major `(out, in)` as
/// PyTorch's `nn.Linear`.
#[derive(Debug, Clone, PartialEq)]
pub struct NerfMlpShape {
    /// The trunk.
    pub trunk: TrunkShape,
    /// Width `D` of the colour head's hidden layer (`n_hidden_neurons_dir`).
    pub dir_hidden: usize,
}

/// Offsets of the heads' packed parameters.
#[derive(Debug, Clone, Copy)]
struct Offsets {
    w_density: usize,
    b_density: usize,
    w_feature: usize,
    b_feature: usize,
    w_colour: usize,
    w_out: usize,
    end: usize,
}

impl NerfMlpShape {
    fn offsets(&self) -> Offsets {
        let (h, d) = (self.trunk.hidden, self.dir_hidden);
        let w_density = self.trunk.n_parameters();
        let b_density = w_density + h;
        let w_feature = b_density + 1;
        let b_feature = w_feature + h * h;
        let w_colour = b_feature + h;
        let w_out = w_colour + d * h;
        Offsets {
            w_density,
            b_density,
            w_feature,
            b_feature,
            w_colour,
            w_out,
            end: w_out + 3 * d + 3,
        }
    }

    /// Number of packed parameters.
    pub(crate) fn n_parameters(&self) -> usize {
        self.offsets().end
    }
}

/// The MLP's layers as Candle tensors (the twin's inputs, and what `pack_parameters` packs).
pub struct NerfLayers<'a> {
    /// The trunk's layers, `W_l (H, in_l)`.
    pub trunk: &'a [Linear],
    /// The density layer, `(1, H)`.
    pub density: &'a Linear,
    /// The intermediate layer, `(H, H)`.
    pub feature: &'a Linear,
    /// The colour layer's feature columns `W_c` `(D, H)` (its direction columns and bias are in
    /// the per-ray part).
    pub colour_feature_weight: Tensor,
    /// The colour head's output layer, `(3, D)`.
    pub colour_out: &'a Linear,
}

/// The layers' parameters flattened in the packed order of [`NerfMlpShape`]: `(P)`.
/// Differentiable (a `cat`).
pub(crate) fn pack_parameters(layers: &NerfLayers) -> candle_core::Result<Tensor> {
    let weight_and_bias = |l: &Linear| -> candle_core::Result<[Tensor; 2]> {
        let w = l.weight();
        let b = match l.bias() {
            Some(b) => b.clone(),
            None => Tensor::zeros(w.dim(0)?, w.dtype(), w.device())?,
        };
        Ok([w.flatten_all()?, b])
    };
    let mut parts = Vec::with_capacity(2 * layers.trunk.len() + 7);
    for l in layers.trunk.iter().chain([layers.density, layers.feature]) {
        parts.extend(weight_and_bias(l)?);
    }
    parts.push(layers.colour_feature_weight.flatten_all()?);
    parts.extend(weight_and_bias(layers.colour_out)?);
    Tensor::cat(&parts, 0)
}

/// The shape of `layers`, the widths read from their weights (the embedding's `E` from the
/// first trunk layer's `(H, E)`); `skip[l]`: trunk layer `l` takes `[y, x]`.
pub fn shape_of(layers: &NerfLayers, skip: Vec<bool>) -> candle_core::Result<NerfMlpShape> {
    Ok(NerfMlpShape {
        trunk: TrunkShape {
            input_dim: layers.trunk[0].weight().dim(1)?,
            hidden: layers.density.weight().dim(1)?,
            skip,
        },
        dir_hidden: layers.colour_out.weight().dim(1)?,
    })
}

/// The whole MLP: the fused `nerf_mlp` where [`use_fused`] allows (f32 on the CPU, fused
/// kernels chosen), else its twin `nerf_mlp_tensor_ops`.
///
/// `x`: `(M, E)` point embedding; `per_ray`: `(N, D)`; `ray_index`: each sample's ray, as a
/// `(M,)` u32 tensor on the inputs' device and as the same values on the host. Returns `(M, 4)`,
/// `[raw density, r, g, b]`.
pub fn mlp_forward(
    x: &Tensor,
    per_ray: &Tensor,
    (ray_index, rays): (&Tensor, &[u32]),
    layers: &NerfLayers,
    shape: &NerfMlpShape,
) -> candle_core::Result<Tensor> {
    if use_fused(x) {
        return nerf_mlp(x, per_ray, rays, &pack_parameters(layers)?, shape);
    }
    nerf_mlp_tensor_ops(x, Some((per_ray, ray_index)), layers, &shape.trunk)
}

/// The raw density alone, `(M, 1)` for the embedding `x` `(M, E)`: fused where [`use_fused`]
/// allows and autograd tracks no parameter (the fused op has no backward pass), else the twin.
pub fn density_forward(
    x: &Tensor,
    layers: &NerfLayers,
    shape: &NerfMlpShape,
) -> candle_core::Result<Tensor> {
    if !use_fused(x) || crate::needs_grad(x) {
        return nerf_mlp_tensor_ops(x, None, layers, &shape.trunk);
    }
    let packed = pack_parameters(layers)?;
    if !crate::needs_grad(&packed) {
        let op = DensityOnly(NerfMlp {
            shape: shape.clone(),
            rays: Vec::new(),
            input_grad: false,
            saved: None,
        });
        return x.contiguous()?.apply_op2_no_bwd(&packed, &Fused(op));
    }
    nerf_mlp_tensor_ops(x, None, layers, &shape.trunk)
}

/// The fused MLP: `x` `(M, E)`, `per_ray` `(N, D)`, `rays` (each sample's ray, `M` entries below
/// `N`), packed `params` `(P)`, all f32 on the CPU; returns `(M, 4)`. Gradients flow to
/// `per_ray` and `params`, and to `x` when autograd tracks it.
pub(crate) fn nerf_mlp(
    x: &Tensor,
    per_ray: &Tensor,
    rays: &[u32],
    params: &Tensor,
    shape: &NerfMlpShape,
) -> candle_core::Result<Tensor> {
    let (m, e) = x.dims2()?;
    let (n, d) = per_ray.dims2()?;
    if e != shape.trunk.input_dim || d != shape.dir_hidden {
        let (x, p) = (x.dims(), per_ray.dims());
        candle_core::bail!("nerf-mlp: embedding {x:?}, per-ray {p:?} for shape {shape:?}");
    }
    check_rays("nerf-mlp", rays, m, n)?;
    let backward = x.track_op() || per_ray.track_op() || params.track_op();
    let op = Fused(NerfMlp {
        shape: shape.clone(),
        rays: rays.to_vec(),
        input_grad: x.track_op(),
        saved: backward.then(|| Mutex::new(Vec::new())),
    });
    let (x, per_ray, params) = (x.contiguous()?, per_ray.contiguous()?, params.contiguous()?);
    if backward {
        x.apply_op3(&per_ray, &params, op)
    } else {
        x.apply_op3_no_bwd(&per_ray, &params, &op)
    }
}

/// The tensor-op twin of [`nerf_mlp`] (any device and dtype, differentiable): `(M, 4)` with
/// `Some((per_ray (N, D), ray_index (M,) u32))`, the raw density `(M, 1)` alone with `None`.
pub(crate) fn nerf_mlp_tensor_ops(
    x: &Tensor,
    colour: Option<(&Tensor, &Tensor)>,
    layers: &NerfLayers,
    trunk: &TrunkShape,
) -> candle_core::Result<Tensor> {
    let lin = |y: &Tensor, l: &Linear| -> candle_core::Result<Tensor> {
        let pre = y.matmul(&l.weight().t()?)?;
        match l.bias() {
            Some(b) => bias_add(&pre, b),
            None => Ok(pre),
        }
    };
    let mut y = x.clone();
    for (i, layer) in layers.trunk.iter().enumerate() {
        if i > 0 && trunk.skip[i] {
            y = Tensor::cat(&[&y, x], 1)?;
        }
        y = lin(&y, layer)?.relu()?;
    }
    let density = lin(&y, layers.density)?;
    let Some((per_ray, ray_index)) = colour else {
        return Ok(density);
    };
    let feature = lin(&y, layers.feature)?;
    let hidden = feature
        .matmul(&layers.colour_feature_weight.t()?)?
        .add(&per_ray.index_select(ray_index, 0)?)?
        .relu()?;
    let rgb = candle_nn::ops::sigmoid(&lin(&hidden, layers.colour_out)?)?;
    Tensor::cat(&[&density, &rgb], 1)
}

struct NerfMlp {
    shape: NerfMlpShape,
    /// Each sample's ray (empty for the density alone).
    rays: Vec<u32>,
    /// Whether the backward pass computes the embedding's gradient.
    input_grad: bool,
    /// Each task's activations, kept by the forward pass for the backward pass (`None`: not
    /// kept, the backward pass recomputes them).
    saved: Option<Mutex<Vec<Option<Activations>>>>,
}

/// The density alone: [`NerfMlp`] without the colour head, as a two-input op.
struct DensityOnly(NerfMlp);

/// One task's activations, `c` rows each.
struct Activations {
    /// Every trunk layer's output, `(c, H)` each.
    trunk: Vec<Vec<f32>>,
    /// `(c)` raw density.
    density: Vec<f32>,
    /// `(c, H)`, `(c, D)` after the ReLU, `(c, 3)` after the sigmoid; empty for the density
    /// alone.
    feature: Vec<f32>,
    hidden: Vec<f32>,
    rgb: Vec<f32>,
}

impl Activations {
    /// Hands the buffers back for reuse ([`recycle`]).
    fn recycle(self) {
        let heads = [self.density, self.feature, self.hidden, self.rgb];
        recycle(self.trunk.into_iter().chain(heads));
    }
}

impl NerfMlp {
    /// The forward pass of `c = x.len() / E` samples; the colour head too when `per_ray` is
    /// given (with the samples' `rays`).
    fn forward(&self, x: &[f32], colour: Option<(&[u32], &[f32])>, p: &[f32]) -> Activations {
        let t = &self.shape.trunk;
        let (e, h, d) = (t.input_dim, t.hidden, self.shape.dir_hidden);
        let c = x.len() / e;
        let mut trunk: Vec<Vec<f32>> = Vec::with_capacity(t.skip.len());
        for i in 0..t.skip.len() {
            let in_i = t.in_dim(i);
            let off = t.offset(i);
            let w = &p[off..off + h * in_i];
            let mut out = task_buffer(c * h);
            match trunk.last() {
                None => times(&mut out, false, (x, e), transposed(w, in_i), (c, e, h)),
                Some(prev) => {
                    times(&mut out, false, (prev, h), transposed(w, in_i), (c, h, h));
                    if t.skip[i] {
                        times(&mut out, true, (x, e), transposed(&w[h..], in_i), (c, e, h));
                    }
                }
            }
            add_bias(&mut out, &p[off + h * in_i..off + h * (in_i + 1)]);
            relu(&mut out);
            trunk.push(out);
        }
        let o = self.shape.offsets();
        let y = trunk.last().expect("at least one trunk layer");
        let mut density = task_buffer(c);
        let (w_density, b_density) = (&p[o.w_density..o.b_density], &p[o.b_density..o.w_feature]);
        linear(&mut density, y, (c, h, 1), w_density, b_density);
        let mut a = Activations {
            trunk: Vec::new(),
            density,
            feature: Vec::new(),
            hidden: Vec::new(),
            rgb: Vec::new(),
        };
        if let Some((rays, per_ray)) = colour {
            a.feature = task_buffer(c * h);
            let (w_f, b_f) = (&p[o.w_feature..o.b_feature], &p[o.b_feature..o.w_colour]);
            linear(&mut a.feature, y, (c, h, h), w_f, b_f);
            a.hidden = task_buffer(c * d);
            let w_c = &p[o.w_colour..o.w_out];
            times(
                &mut a.hidden,
                false,
                (&a.feature, h),
                transposed(w_c, h),
                (c, h, d),
            );
            add_per_ray_relu(&mut a.hidden, rays, per_ray);
            a.rgb = rgb_head(&a.hidden, &p[o.w_out..o.end]);
        }
        a.trunk = trunk;
        a
    }

    /// The backward pass of one task's samples (embedding `x`, rays `rays`, output gradient
    /// `grad` `(c, 4)`): the embedding's gradient into `d_x` (when asked for), the parameter
    /// and per-ray gradients added into `sums`.
    #[allow(clippy::too_many_arguments)]
    fn backward(
        &self,
        (x, rays, grad): (&[f32], &[u32], &[f32]),
        per_ray: &[f32],
        p: &[f32],
        saved: Option<Activations>,
        d_x: Option<&mut [f32]>,
        sums: &mut GradientSums,
    ) {
        let (h, d) = (self.shape.trunk.hidden, self.shape.dir_hidden);
        let o = self.shape.offsets();
        let c = rays.len();
        let a = saved.unwrap_or_else(|| self.forward(x, Some((rays, per_ray)), p));
        let dp = &mut sums.params;
        // Colour head: the sigmoid, the output layer, the ReLU, the per-ray part.
        let d_hidden = rgb_head_backward(
            (grad, &a.rgb, &a.hidden),
            (&p[o.w_out..o.end], &mut dp[o.w_out..o.end]),
        );
        add_by_ray(&mut sums.per_ray, &d_hidden, rays);
        let dw_c = (&mut dp[o.w_colour..o.w_out], h);
        weight_grad(dw_c, None, &d_hidden, (&a.feature, h), (c, d, h));
        let mut d_feature = task_buffer(c * h);
        let w_c = as_is(&p[o.w_colour..o.w_out], h);
        times(&mut d_feature, false, (&d_hidden, d), w_c, (c, d, h));
        // The intermediate and density layers, both on the trunk's output.
        let y = a.trunk.last().expect("at least one trunk layer");
        let (dw_f, db_f) = dp[o.w_feature..o.w_colour].split_at_mut(h * h);
        weight_grad((dw_f, h), Some(db_f), &d_feature, (y, h), (c, h, h));
        let mut d_y = task_buffer(c * h);
        let w_f = as_is(&p[o.w_feature..o.b_feature], h);
        times(&mut d_y, false, (&d_feature, h), w_f, (c, h, h));
        let d_density: Vec<f32> = grad.chunks_exact(4).map(|g| g[0]).collect();
        let (dw_s, db_s) = dp[o.w_density..o.w_feature].split_at_mut(h);
        weight_grad((dw_s, h), Some(db_s), &d_density, (y, h), (c, 1, h));
        let w_s = as_is(&p[o.w_density..o.b_density], h);
        times(&mut d_y, true, (&d_density, 1), w_s, (c, 1, h));
        self.trunk_backward(&a.trunk, x, d_y, p, d_x, dp);
        recycle([d_hidden, d_feature]);
        a.recycle();
    }

    /// Back through the trunk from the gradient `d_y` `(c, H)` of its output: weight and bias
    /// gradients added into `dp`, the embedding's gradient into `d_x` when given.
    fn trunk_backward(
        &self,
        outputs: &[Vec<f32>],
        x: &[f32],
        mut d_y: Vec<f32>,
        p: &[f32],
        mut d_x: Option<&mut [f32]>,
        dp: &mut [f32],
    ) {
        let t = &self.shape.trunk;
        let (e, h) = (t.input_dim, t.hidden);
        let c = x.len() / e;
        let mut spare = task_buffer(if outputs.len() > 1 { c * h } else { 0 });
        for i in (0..t.skip.len()).rev() {
            let in_i = t.in_dim(i);
            let off = t.offset(i);
            let w = &p[off..off + h * in_i];
            let (dw, rest) = dp[off..].split_at_mut(h * in_i);
            mask(&mut d_y, &outputs[i]);
            // The embedding's columns: all of layer 0's, the last E of a skip layer's.
            let x_columns = match i {
                0 => Some(0),
                _ if t.skip[i] => Some(h),
                _ => None,
            };
            if i > 0 {
                let prev = (&outputs[i - 1][..], h);
                weight_grad((dw, in_i), Some(&mut rest[..h]), &d_y, prev, (c, h, h));
            }
            if let Some(col) = x_columns {
                let db = (i == 0).then_some(&mut rest[..h]);
                weight_grad((&mut dw[col..], in_i), db, &d_y, (x, e), (c, h, e));
                if let Some(d_x) = d_x.as_deref_mut() {
                    times(d_x, true, (&d_y, h), as_is(&w[col..], in_i), (c, h, e));
                }
            }
            if i > 0 {
                times(&mut spare, false, (&d_y, h), as_is(w, in_i), (c, h, h));
                std::mem::swap(&mut d_y, &mut spare);
            }
        }
        recycle([d_y, spare]);
    }
}

impl CpuKernel<3> for NerfMlp {
    const NAME: &'static str = "nerf-mlp";

    fn cpu_forward(&self, inputs: [CpuInput; 3]) -> KernelOutput {
        let [x, per_ray, params] = CpuInput::all_f32(&inputs, Self::NAME)?;
        check_parameters(&self.shape, params, Self::NAME)?;
        let e = self.shape.trunk.input_dim;
        let m = self.rays.len();
        let mut out = vec![0f32; m * 4];
        let keep = self.saved.is_some();
        let activations: Vec<Option<Activations>> = out
            .par_chunks_mut(ROWS_PER_TASK * 4)
            .zip(x.par_chunks(ROWS_PER_TASK * e))
            .zip(self.rays.par_chunks(ROWS_PER_TASK))
            .map(|((out, x), rays)| {
                let a = self.forward(x, Some((rays, per_ray)), params);
                for (i, row) in out.chunks_exact_mut(4).enumerate() {
                    row[0] = a.density[i];
                    row[1..].copy_from_slice(&a.rgb[3 * i..3 * i + 3]);
                }
                if keep {
                    return Some(a);
                }
                a.recycle();
                None
            })
            .collect();
        if let Some(saved) = &self.saved {
            *saved.lock().expect("nerf-mlp lock") = activations;
        }
        Ok((out, Shape::from((m, 4))))
    }

    fn gradients(&self, [x, per_ray, params]: [&Tensor; 3], grad: &Tensor) -> KernelGradients<3> {
        let e = self.shape.trunk.input_dim;
        let n_params = self.shape.n_parameters();
        let n_per_ray = per_ray.elem_count();
        let [x_v, per_ray_v, p, g] = host_values([x, per_ray, params, grad])?;
        let mut d_x = vec![0f32; if self.input_grad { x_v.len() } else { 0 }];
        let block = ROWS_PER_TASK * BLOCKS_PER_SUM;
        // Without the embedding's gradient, `d_x` is empty: each block gets an empty slice.
        let d_x_block = if self.input_grad { block * e } else { 1 };
        let n_blocks = self.rays.len().div_ceil(block);
        let mut d_x_blocks: Vec<&mut [f32]> = d_x.chunks_mut(d_x_block).collect();
        d_x_blocks.resize_with(n_blocks, Default::default);
        // The forward pass's activations, one a task (recomputed where none were kept).
        let mut saved = match &self.saved {
            Some(s) => std::mem::take(&mut *s.lock().expect("nerf-mlp lock")),
            None => Vec::new(),
        };
        saved.resize_with(self.rays.len().div_ceil(ROWS_PER_TASK), || None);
        let partial: Vec<GradientSums> = d_x_blocks
            .into_par_iter()
            .zip(saved.par_chunks_mut(BLOCKS_PER_SUM))
            .zip(x_v.par_chunks(block * e))
            .zip(self.rays.par_chunks(block))
            .zip(g.par_chunks(block * 4))
            .map(|((((d_x, saved), x), rays), g)| {
                let mut sums = GradientSums::zeros(n_params, n_per_ray);
                let mut d_x_tasks = d_x.chunks_mut(ROWS_PER_TASK * e);
                for (((x, rays), g), a) in x
                    .chunks(ROWS_PER_TASK * e)
                    .zip(rays.chunks(ROWS_PER_TASK))
                    .zip(g.chunks(ROWS_PER_TASK * 4))
                    .zip(saved.iter_mut())
                {
                    let d_x = d_x_tasks.next();
                    self.backward((x, rays, g), &per_ray_v, &p, a.take(), d_x, &mut sums);
                }
                sums
            })
            .collect();
        let sums = GradientSums::add_in_order(partial, n_params, n_per_ray);
        let dev = x.device();
        let d_x = match self.input_grad {
            true => Some(Tensor::from_vec(d_x, x.shape(), dev)?),
            false => None,
        };
        Ok([
            d_x,
            Some(Tensor::from_vec(sums.per_ray, per_ray.shape(), dev)?),
            Some(Tensor::from_vec(sums.params, n_params, dev)?),
        ])
    }
}

impl CpuKernel<2> for DensityOnly {
    const NAME: &'static str = "nerf-density";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [x, params] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let mlp = &self.0;
        check_parameters(&mlp.shape, params, Self::NAME)?;
        let e = mlp.shape.trunk.input_dim;
        let m = x.len() / e;
        let mut out = vec![0f32; m];
        out.par_chunks_mut(ROWS_PER_TASK)
            .zip(x.par_chunks(ROWS_PER_TASK * e))
            .for_each(|(out, x)| {
                let a = mlp.forward(x, None, params);
                out.copy_from_slice(&a.density);
                a.recycle();
            });
        Ok((out, Shape::from((m, 1))))
    }
}

/// An error naming `op` unless `params` holds `shape`'s number of parameters.
fn check_parameters(shape: &NerfMlpShape, params: &[f32], op: &str) -> candle_core::Result<()> {
    if params.len() != shape.n_parameters() || shape.trunk.skip.is_empty() {
        candle_core::bail!(
            "{op}: {} parameters, expected {} ({} trunk layers)",
            params.len(),
            shape.n_parameters(),
            shape.trunk.skip.len()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::weighted_sum_gradients;
    use candle_core::{Device, Var};
    use nerf_core::compare::{assert_close, max_abs_difference};

    /// A linear layer of `(out, in)` random variables.
    fn layer(out: usize, input: usize) -> (Var, Var, Linear) {
        let dev = Device::Cpu;
        let w = Var::randn(0f32, 0.4, (out, input), &dev).unwrap();
        let b = Var::randn(0.05f32, 0.1, out, &dev).unwrap();
        let l = Linear::new(w.as_tensor().clone(), Some(b.as_tensor().clone()));
        (w, b, l)
    }

    #[test]
    fn fused_matches_tensor_ops_forward_and_backward() {
        let dev = Device::Cpu;
        let (e, h, d) = (7, 12, 5);
        let skip = vec![false, false, true, false];
        let trunk: Vec<(Var, Var, Linear)> = (0..4)
            .map(|i| {
                layer(
                    h,
                    if i == 0 {
                        e
                    } else if skip[i] {
                        h + e
                    } else {
                        h
                    },
                )
            })
            .collect();
        let (density, feature, colour, out) = (layer(1, h), layer(h, h), layer(d, h), layer(3, d));
        let trunk_layers: Vec<Linear> = trunk.iter().map(|t| t.2.clone()).collect();
        let layers = NerfLayers {
            trunk: &trunk_layers,
            density: &density.2,
            feature: &feature.2,
            colour_feature_weight: colour.0.as_tensor().clone(),
            colour_out: &out.2,
        };
        let shape = shape_of(&layers, skip).unwrap();
        // 600 samples of 7 rays (more than two tasks, a ray split across tasks, one ray with
        // no sample, and one out of order); the embedding tracked, as under camera refinement.
        let m = 600;
        let mut rays: Vec<u32> = (0..m as u32).map(|i| (i * 7 / m as u32).min(5)).collect();
        rays[10] = 6;
        let x = Var::randn(0f32, 1.0, (m, e), &dev).unwrap();
        let per_ray = Var::randn(0f32, 0.5, (7, d), &dev).unwrap();
        let index = Tensor::new(rays.as_slice(), &dev).unwrap();
        let packed = pack_parameters(&layers).unwrap();
        let fast = nerf_mlp(&x, &per_ray, &rays, &packed, &shape).unwrap();
        let slow = nerf_mlp_tensor_ops(&x, Some((&per_ray, &index)), &layers, &shape.trunk);
        let slow = slow.unwrap();
        let diff = max_abs_difference(&fast, &slow).unwrap();
        assert!(diff < 1e-5, "forward {diff}");
        let weight = Tensor::randn(0f32, 1.0, (m, 4), &dev).unwrap();
        let (gf, gs) = (
            weighted_sum_gradients(&fast, &weight),
            weighted_sum_gradients(&slow, &weight),
        );
        let mut vars: Vec<&Var> = trunk.iter().flat_map(|t| [&t.0, &t.1]).collect();
        vars.extend([&density.0, &density.1, &feature.0, &feature.1, &colour.0]);
        vars.extend([&out.0, &out.1, &x, &per_ray]);
        for v in vars {
            let (a, b) = (gf.get(v).unwrap(), gs.get(v).unwrap());
            assert_close(a, b, 1e-5, &format!("gradient {:?}", v.dims()));
        }
        // The density alone (fused, nothing tracked) equals the first column.
        let detach = |l: &Linear| Linear::new(l.weight().detach(), l.bias().map(|b| b.detach()));
        let plain_trunk: Vec<Linear> = trunk_layers.iter().map(detach).collect();
        let (pd, pf, po) = (detach(&density.2), detach(&feature.2), detach(&out.2));
        let plain = NerfLayers {
            trunk: &plain_trunk,
            density: &pd,
            feature: &pf,
            colour_feature_weight: colour.0.detach(),
            colour_out: &po,
        };
        let alone = density_forward(&x.detach(), &plain, &shape).unwrap();
        let first = fast.narrow(1, 0, 1).unwrap();
        assert!(max_abs_difference(&alone, &first).unwrap() < 1e-6);
    }
}
