//! The hash-grid field's training step without an autograd graph over the samples: rays to
//! marched samples to encoding to MLPs to compositing to the loss, then back to the MLPs'
//! and the table's gradients, on host buffers between the fused kernels' own passes.
//!
//! Through autograd the same step builds, per segment of the march, a graph of the box
//! mapping, the encoding, the MLPs, the density activation and the index bookkeeping, then
//! joins the segments for the compositing, the background and the loss; its backward pass
//! walks all of that again, allocating a gradient tensor per node. Here each stage is one
//! pass over plain buffers: the segments' encodings and MLP outputs are appended as they are
//! evaluated, the loss's gradient goes straight into the compositing's backward pass, and the
//! table's gradient into its sink for the sparse Adam. The per-ray half of the colour MLP's
//! first layer (the direction encoding) is a product per ray, forward and back; the only
//! Candle ops left are those of per-image appearance vectors, when the model has them (`N`
//! rows, not `M` samples: their gradient is one small backward pass).
//!
//! Its twin is the autograd step (`nerf::train::step`), held equal by a test there.

use anyhow::{bail, Result};
use candle_core::{DType, Tensor};

use super::host_values::{table_values, HostValues};
use super::{DensityActivation, Ngp, GEO_FEATURES, HIDDEN, SH_DIM};
use crate::fused_step::{FusedBatch, FusedGradients};
use nerf_hash_grid::ngp_mlp::{mlp_gradients, MlpShape};
use nerf_hash_grid::spherical_harmonics::sh_basis_values;
use nerf_kernels::composite::{packed_backward, packed_forward, PackedRays};
use nerf_kernels::gemm::gemm_f32;
use nerf_render::skipping::{march_packed, MarchedSegment};

impl DensityActivation {
    /// σ of the raw density `x` (before the box's inside flag).
    #[inline]
    pub(crate) fn value(self, x: f32) -> f32 {
        match self {
            Self::TruncExp => x.exp(),
            Self::Softplus => (x.exp() + 1.0).ln(),
        }
    }

    /// The gradient `dσ/dx` autograd takes: `exp(min(x, 15))` for [`super::trunc_exp`], the
    /// logistic function for softplus.
    #[inline]
    pub(crate) fn slope(self, x: f32) -> f32 {
        match self {
            Self::TruncExp => x.min(super::TRUNC_EXP_MAX as f32).exp(),
            Self::Softplus => 1.0 / (1.0 + (-x).exp()),
        }
    }
}

/// The evaluated samples' values, appended segment by segment in evaluation order.
#[derive(Default)]
struct Evaluated {
    /// Points in the box's unit cube, 3 values each (the encoding's input).
    unit: Vec<f32>,
    /// 1 inside the box, 0 outside.
    inside: Vec<f32>,
    /// The encoding, `L·F` values each.
    encoding: Vec<f32>,
    /// The raw density.
    raw: Vec<f32>,
    /// σ.
    sigma: Vec<f32>,
    /// Colour, 3 values each.
    rgb: Vec<f32>,
    /// Each sample's ray.
    rays: Vec<u32>,
}

impl Ngp {
    /// Whether [`Ngp::fused_gradients`] can run: f32 parameters on the CPU with the fused
    /// kernels chosen, and a sink that takes the table's gradient.
    pub(crate) fn has_fused_step(&self) -> bool {
        nerf_kernels::use_fused(&self.table) && self.gradient.is_some()
    }

    /// One training step's forward and backward passes over `batch` (see the module): the
    /// MSE, the sample counts, and the gradients of the MLPs' (and appearance) variables; the
    /// table's gradient is added into the model's sink ([`Ngp::with_table_gradient`]).
    pub(crate) fn fused_gradients(&self, batch: &FusedBatch) -> Result<FusedGradients> {
        let Some(sink) = &self.gradient else {
            bail!("the fused hash-grid step needs the table gradient's sink");
        };
        let rays = batch.rays;
        let n = rays.len();
        anyhow::ensure!(
            batch.target.len() == 3 * n && batch.background.len() == 3 * n,
            "fused step: {} target and {} background values for {n} rays",
            batch.target.len(),
            batch.background.len()
        );
        let grid = &self.grid;
        let shape = self.mlp_shape();
        let params = self.packed_mlp_values()?;
        let directions = rays
            .directions
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        let sh = sh_basis_values(&directions);
        let color0 = self.color[0].weight().flatten_all()?.to_vec1::<f32>()?;
        let color0_bias = match self.color[0].bias() {
            Some(b) => b.to_vec1::<f32>()?,
            None => vec![0.0; HIDDEN],
        };
        let mut per_ray_values = per_ray_direction_term(&sh, &color0, &color0_bias);
        // With per-image appearance its term is added, tracked: its gradient is one small
        // backward pass at the end.
        let appearance = match &self.appearance {
            Some(a) => {
                let term = a.per_ray(rays.camera_index.as_ref())?;
                let term = term.broadcast_as((n, HIDDEN))?.contiguous()?;
                let values = term.detach().flatten_all()?.to_vec1::<f32>()?;
                per_ray_values
                    .iter_mut()
                    .zip(values)
                    .for_each(|(p, v)| *p += v);
                Some(term)
            }
            None => None,
        };
        let activation = self.params.density_activation;
        let (storage, layout) = self.table.storage_and_layout();
        let table = table_values(&storage, layout)?;
        let mut e = Evaluated::default();
        let (index, samples) = march_packed(
            batch.occupancy,
            batch.early_termination,
            rays,
            batch.lengths,
            |segment: MarchedSegment| {
                let HostValues {
                    unit,
                    inside,
                    encoding,
                    out,
                } = self.evaluate_on_host(
                    (table, &params),
                    segment.points,
                    (&segment.ray_index, &per_ray_values),
                );
                let sigma: Vec<f32> = out
                    .chunks_exact(4)
                    .zip(&inside)
                    .map(|(o, i)| activation.value(o[0]) * i)
                    .collect();
                e.raw.extend(out.chunks_exact(4).map(|o| o[0]));
                e.rgb
                    .extend(out.chunks_exact(4).flat_map(|o| [o[1], o[2], o[3]]));
                e.sigma.extend_from_slice(&sigma);
                e.unit.extend(unit);
                e.inside.extend(inside);
                e.encoding.extend(encoding);
                e.rays.extend(segment.ray_index);
                Ok(sigma)
            },
        )?;
        drop(storage);
        // Compositing, the background and the loss, forward and back.
        let s = batch.lengths.dim(1)?;
        let lengths = batch
            .lengths
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        let packed = PackedRays::new(index, lengths, (n, s));
        let composited = packed_forward(&packed, &e.sigma, &e.rgb, 3);
        let (squared, d_out) = colour_loss(&composited, batch.target, batch.background);
        let mse = squared / (3 * n).max(1) as f64;
        if !mse.is_finite() {
            bail!("the renderer produced a non-finite colour (NaN or infinity); check the field's density and feature");
        }
        let (d_sigma, d_rgb) = packed_backward(&packed, &e.sigma, &e.rgb, &d_out, 3);
        let m = e.rays.len();
        let mut d_mlp = vec![0f32; 4 * m];
        for (i, d) in d_mlp.chunks_exact_mut(4).enumerate() {
            d[0] = d_sigma[i] * activation.slope(e.raw[i]) * e.inside[i];
            d[1..].copy_from_slice(&d_rgb[3 * i..3 * i + 3]);
        }
        let (d_encoding, sums) = mlp_gradients(
            shape,
            &e.encoding,
            (&e.rays, &per_ray_values),
            &params,
            &d_mlp,
        );
        sink.add(grid, &e.unit, &d_encoding);
        // The appearance vectors' gradient by autograd (a store of no variable without
        // them: Candle makes a `GradStore` only by a backward pass), then the MLPs'.
        let device = self.table.device();
        let d_per_ray = &sums.per_ray;
        let mut grads = match appearance {
            Some(term) => {
                let d = Tensor::from_slice(d_per_ray, (n, HIDDEN), device)?;
                (term * d)?.sum_all()?.backward()?
            }
            None => Tensor::zeros((), DType::F32, device)?.backward()?,
        };
        self.insert_mlp_gradients(&mut grads, &sums.params, shape)?;
        let (d_color0, d_color0_bias) =
            per_ray_direction_gradient(d_per_ray, &sh, &sums.params, shape);
        let w = self.color[0].weight();
        grads.insert(w, Tensor::from_vec(d_color0, w.dims(), device)?);
        if let Some(b) = self.color[0].bias() {
            grads.insert(b, Tensor::from_vec(d_color0_bias, b.dims(), device)?);
        }
        Ok(FusedGradients {
            mse,
            samples,
            grads,
        })
    }

    /// Adds the packed MLP gradient `d` ([`MlpShape`]'s order) to `grads`, by variable, but for
    /// the colour MLP's first layer ([`per_ray_direction_gradient`]).
    fn insert_mlp_gradients(
        &self,
        grads: &mut candle_core::backprop::GradStore,
        d: &[f32],
        shape: MlpShape,
    ) -> Result<()> {
        let device = self.table.device();
        let r = shape.ranges();
        let part = |k: usize, dims: &[usize]| Tensor::from_slice(&d[r[k].clone()], dims, device);
        let layers = [
            (&self.density[0], 0),
            (&self.density[1], 2),
            (&self.color[1], 5),
            (&self.color[2], 7),
        ];
        for (layer, k) in layers {
            let w = layer.weight();
            grads.insert(w, part(k, w.dims())?);
            if let Some(b) = layer.bias() {
                grads.insert(b, part(k + 1, b.dims())?);
            }
        }
        Ok(())
    }
}

/// The direction half of the colour MLP's first layer, per ray: `sh` `(N, 16)` (each ray's
/// [`sh_basis`]) times the direction columns of its weight `w` `(H, G + 16)` (row-major),
/// plus its bias `b` `(H)`: `(N, H)`.
fn per_ray_direction_term(sh: &[f32], w: &[f32], b: &[f32]) -> Vec<f32> {
    let (n, h) = (sh.len() / SH_DIM, b.len());
    let width = GEO_FEATURES + SH_DIM;
    let mut out = vec![0f32; n * h];
    // out[r, j] = Σ_k sh[r, k] · w[j, G + k]: the weight's direction columns, transposed.
    gemm_f32(
        (n, h, SH_DIM),
        &mut out,
        h,
        false,
        sh,
        (SH_DIM, 1),
        &w[GEO_FEATURES..],
        (1, width),
        true,
    );
    for row in out.chunks_exact_mut(h) {
        row.iter_mut().zip(b).for_each(|(v, b)| *v += b);
    }
    out
}

/// The gradient of the colour MLP's first weight `(H, G + 16)` (row-major) and bias `(H)`:
/// the geometry columns from the packed MLP gradient `d_params` ([`MlpShape`]'s `Wg`), the
/// direction columns `d_per_ray`ᵀ · `sh` from the per-ray term's gradient `d_per_ray`
/// `(N, H)` and the rays' `sh` `(N, 16)`, and the bias the column sums of `d_per_ray`.
fn per_ray_direction_gradient(
    d_per_ray: &[f32],
    sh: &[f32],
    d_params: &[f32],
    shape: MlpShape,
) -> (Vec<f32>, Vec<f32>) {
    let (n, h) = (sh.len() / SH_DIM, shape.hidden);
    let width = GEO_FEATURES + SH_DIM;
    let mut d_w = vec![0f32; h * width];
    let d_geo = &d_params[shape.ranges()[4].clone()];
    for (row, geo) in d_w
        .chunks_exact_mut(width)
        .zip(d_geo.chunks_exact(GEO_FEATURES))
    {
        row[..GEO_FEATURES].copy_from_slice(geo);
    }
    // d_w[j, G + k] = Σ_r d_per_ray[r, j] · sh[r, k].
    gemm_f32(
        (h, SH_DIM, n),
        &mut d_w[GEO_FEATURES..],
        width,
        false,
        d_per_ray,
        (1, h),
        sh,
        (SH_DIM, 1),
        true,
    );
    let mut d_b = vec![0f32; h];
    for row in d_per_ray.chunks_exact(h) {
        d_b.iter_mut().zip(row).for_each(|(s, v)| *s += v);
    }
    (d_w, d_b)
}

/// Each ray's colour `c + (1 − opacity)·b` against its target, from composited rows
/// `[r, g, b, depth, opacity]` (N of them), the background `b` and the target (3 values a
/// ray): the summed squared error and its gradient per composited row, for the mean over the
/// `3N` values (the depth's gradient is 0).
fn colour_loss(composited: &[f32], target: &[f32], background: &[f32]) -> (f64, Vec<f32>) {
    let n = target.len() / 3;
    let scale = 2.0 / (3 * n).max(1) as f32;
    let mut squared = 0f64;
    let mut d_out = vec![0f32; 5 * n];
    for (ray, (row, d)) in composited
        .chunks_exact(5)
        .zip(d_out.chunks_exact_mut(5))
        .enumerate()
    {
        let (t, b) = (
            &target[3 * ray..3 * ray + 3],
            &background[3 * ray..3 * ray + 3],
        );
        let transparency = 1.0 - row[4];
        let mut d_opacity = 0f32;
        for c in 0..3 {
            let diff = row[c] + transparency * b[c] - t[c];
            squared += f64::from(diff * diff);
            d[c] = scale * diff;
            d_opacity -= d[c] * b[c];
        }
        d[4] = d_opacity;
    }
    (squared, d_out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use candle_nn::{VarBuilder, VarMap};
    use nerf_core::contraction::Contraction;
    use nerf_kernels::test_support::uniform_values;

    #[test]
    fn fused_density_matches_the_tensor_path() {
        let dev = Device::Cpu;
        for contraction in [Contraction::None, Contraction::LInf] {
            let params = super::super::NgpParams {
                contraction,
                ..super::super::small_test_params()
            };
            let mut varmap = VarMap::new();
            let model =
                Ngp::new(&params, VarBuilder::from_varmap(&varmap, DType::F32, &dev)).unwrap();
            let table = uniform_values(model.table.elem_count(), 4, -1f32, 1.0);
            let table = Tensor::from_vec(table, model.table.shape(), &dev).unwrap();
            varmap.set_one(super::super::TABLE, &table).unwrap();
            // 1000 points in [-2.5, 2.5]³: some outside the box, some beyond the contraction's
            // unit cube.
            let points = uniform_values(3000, 8, -2.5f32, 2.5);
            let fused = model.density_values(&points).unwrap();
            let twin = model
                .density(&Tensor::from_vec(points.clone(), (1000, 3), &dev).unwrap())
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap();
            assert!(twin.contains(&0.0) && twin.iter().any(|&v| v > 0.0));
            for (i, (a, b)) in fused.iter().zip(&twin).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-5 * b.abs().max(1e-3),
                    "{contraction:?} point {i}: {a} against {b}"
                );
            }
        }
    }
}
