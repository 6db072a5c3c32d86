//! An Instant-NGP-class field: a multiresolution hash encoding of the point
//! ([`nerf_hash_grid::hash_grid`]) and two small MLPs.
//!
//! * The point is mapped from the field's axis-aligned box to [0, 1]³ and encoded (`L·F`
//!   features); outside the box the density is 0. With a scene contraction
//!   ([`nerf_core::contraction`], `implicit_function.contraction: linf`) the point is
//!   contracted first and the box is in contracted space (`[-2, 2]³` covers all of space).
//! * `density_mlp`: Linear(L·F, 64) + ReLU → Linear(64, 16); output 0 is the raw density
//!   (through `trunc_exp`, or softplus), outputs 1..16 are 15 geometry features.
//! * `color_mlp`: Linear(15 + 16, 64) + ReLU → Linear(64, 64) + ReLU → Linear(64, 3) + sigmoid,
//!   on the geometry features and the degree-4 real spherical harmonics of the direction
//!   ([`nerf_hash_grid::spherical_harmonics::sh_basis`]). The direction half of the first layer depends only on the ray, so it is
//!   applied once per ray (as in [`crate::nerf`]).
//!
//! Parameters: `encoding.table` `(L·T, F)` (initialised U(−1e‑4, 1e‑4), as instant-ngp) and
//! `density_mlp.{0,2}` / `color_mlp.{0,2,4}` `.weight` `(out, in)` and `.bias` (PyTorch's
//! default initialisation).

use std::sync::Arc;

use anyhow::Result;
use candle_core::{DType, Device, Tensor};
use candle_nn::{Init, Linear, VarBuilder, VarMap};

use crate::appearance::Appearance;
use crate::fused_step::{FusedBatch, FusedGradients};
use crate::nerf::linear;
use crate::trainable::{
    linear_init_bound, named_vars, seed_uniform, BoxedField, DenseGroup, FieldSpec, ParamGroups,
    SparseRowsGroup, TrainableField, TrainingFastPaths,
};
use nerf_hash_grid::box_unit::box_unit;
use nerf_hash_grid::hash_grid::{hash_encode, HashGridParams, TableGradient};
use nerf_hash_grid::ngp_mlp::{mlp_forward, MlpLayers};
use nerf_hash_grid::spherical_harmonics::{sh_encode, SH_DIM};
use nerf_render::field::{Field, FieldFastPaths, FieldOutput};
use nerf_render::sampler::RaySamples;

mod fused_step;
mod host_values;

pub use crate::ngp_config::{DensityActivation, NgpParams, KIND};

/// Width of the hidden layers of both MLPs.
pub const HIDDEN: usize = 64;
/// Geometry features passed from the density MLP to the colour MLP.
pub const GEO_FEATURES: usize = 15;
/// Where [`trunc_exp`]'s gradient stops growing (instant-ngp's 15).
pub(crate) const TRUNC_EXP_MAX: f64 = 15.0;

/// `exp(x)` whose gradient is `exp(min(x, 15))·g` (instant-ngp's `trunc_exp`: the value is
/// exact, the gradient cannot overflow). Tensor ops only: `(exp(x) − e·x)` detached plus
/// `e·x` with `e = exp(min(x, 15))` detached. Any shape.
pub(crate) fn trunc_exp(x: &Tensor) -> Result<Tensor> {
    let e = x.detach().clamp(f64::NEG_INFINITY, TRUNC_EXP_MAX)?.exp()?;
    let constant = (x.detach().exp()? - (&e * x.detach())?)?;
    Ok(((&e * x)? + constant)?)
}

/// `nn.Linear(in_dim, out_dim)` with PyTorch's default initialisation, under `vb`.
fn new_linear(in_dim: usize, out_dim: usize, vb: VarBuilder) -> Result<Linear> {
    let bound = 1.0 / (in_dim as f64).sqrt();
    let init = Init::Uniform {
        lo: -bound,
        up: bound,
    };
    let w = vb.get_with_hints((out_dim, in_dim), "weight", init)?;
    let b = vb.get_with_hints(out_dim, "bias", init)?;
    Ok(Linear::new(w, Some(b)))
}

/// The NGP model: the hash table and the two MLPs.
#[derive(Debug, Clone)]
pub struct Ngp {
    /// The sizes the model was built with.
    pub params: NgpParams,
    /// The hash encoding's shape (`params.grid()`, kept: every evaluation reads it).
    grid: HashGridParams,
    table: Tensor,
    density: [Linear; 2],
    color: [Linear; 3],
    appearance: Option<Appearance>,
    /// Where the fused encoding leaves the table's gradient, when training with the sparse
    /// optimiser ([`Ngp::with_table_gradient`]).
    gradient: Option<Arc<TableGradient>>,
}

impl Ngp {
    /// Builds the model; parameters are created in (or loaded from) `vb`.
    pub fn new(params: &NgpParams, vb: VarBuilder) -> Result<Self> {
        params.validate()?;
        let g = &params.grid();
        let init = Init::Uniform {
            lo: -1e-4,
            up: 1e-4,
        };
        let table = vb.get_with_hints((g.n_rows(), g.n_features), "encoding.table", init)?;
        let d = vb.pp("density_mlp");
        let c = vb.pp("color_mlp");
        Ok(Self {
            params: params.clone(),
            grid: *g,
            table,
            density: [
                new_linear(g.output_dim(), HIDDEN, d.pp("0"))?,
                new_linear(HIDDEN, 1 + GEO_FEATURES, d.pp("2"))?,
            ],
            color: [
                new_linear(GEO_FEATURES + SH_DIM, HIDDEN, c.pp("0"))?,
                new_linear(HIDDEN, HIDDEN, c.pp("2"))?,
                new_linear(HIDDEN, 3, c.pp("4"))?,
            ],
            appearance: match &params.appearance() {
                Some(a) => Appearance::new(a, HIDDEN, &vb)?,
                None => None,
            },
            gradient: None,
        })
    }

    /// The same model whose fused encoding hands the table's gradient to `gradient` instead of
    /// autograd (for `nerf::train::sparse_adam::SparseAdam`).
    pub(crate) fn with_table_gradient(mut self, gradient: Arc<TableGradient>) -> Self {
        self.gradient = Some(gradient);
        self
    }

    #[cfg(test)]
    /// The hash table `(L·T, F)` (the parameter the sparse optimiser treats row by row).
    pub(crate) fn table(&self) -> &Tensor {
        &self.table
    }

    /// `points` `(M, 3)` in world units, contracted ([`NgpParams::contraction`]) and mapped
    /// to [0, 1]³ by the box: `(M, 3)`, and `(M, 1)` with 1 inside the box (faces included),
    /// 0 outside.
    fn normalise(&self, points: &Tensor) -> Result<(Tensor, Tensor)> {
        let points = &self.params.contraction.contract_tensor(points)?;
        let [lo, hi] = self.params.aabb;
        let scale = std::array::from_fn(|k| 1.0 / (hi[k] - lo[k]) as f32);
        Ok(box_unit(points, lo.map(|v| v as f32), scale)?)
    }

    /// The hash encoding `(M, L·F)` of `points` `(M, 3)` mapped into the box, and whether each
    /// point is inside it `(M, 1)`.
    fn encode(&self, points: &Tensor) -> Result<(Tensor, Tensor)> {
        let (unit, inside) = self.normalise(points)?;
        let enc = hash_encode(&unit, &self.table, &self.grid, self.gradient.as_ref())?;
        Ok((enc, inside))
    }

    /// σ `(M, 1)` (0 outside the box) and the geometry features `(M, 15)` at `points` `(M, 3)`.
    pub(crate) fn geometry(&self, points: &Tensor) -> Result<(Tensor, Tensor)> {
        let (enc, inside) = self.encode(points)?;
        let h = linear(&self.density[0], &enc)?.relu()?;
        let out = linear(&self.density[1], &h)?;
        let sigma = self.activate(&out.narrow(1, 0, 1)?, &inside)?;
        Ok((sigma, out.narrow(1, 1, GEO_FEATURES)?))
    }

    /// The per-ray part of the colour MLP's first layer: the SH of `directions` `(N, 3)` times
    /// its direction columns, plus its bias, plus the appearance term of each ray's training
    /// image `camera_index` `(N,)` u32 (of the mean image without): `(N, 64)`.
    fn per_ray(&self, directions: &Tensor, camera_index: Option<&Tensor>) -> Result<Tensor> {
        let w_sh = self.color[0].weight().narrow(1, GEO_FEATURES, SH_DIM)?;
        let mut per_ray = sh_encode(directions)?.matmul(&w_sh.t()?)?;
        if let Some(b) = self.color[0].bias() {
            per_ray = per_ray.broadcast_add(b)?;
        }
        if let Some(appearance) = &self.appearance {
            per_ray = per_ray.broadcast_add(&appearance.per_ray(camera_index)?)?;
        }
        Ok(per_ray)
    }

    /// Both MLPs on the encoding `enc` `(M, L·F)` of samples on rays `ray_index` `(M,)` u32
    /// (the same indices as `rays`) whose [`Ngp::per_ray`] part is `per_ray` `(N, 64)`:
    /// `(M, 4)`, the raw density and RGB.
    /// The fused kernel or its tensor-op twin, as [`mlp_forward`] chooses.
    fn mlps(
        &self,
        enc: &Tensor,
        per_ray: &Tensor,
        (ray_index, rays): (&Tensor, &[u32]),
    ) -> Result<Tensor> {
        let bias = |l: &Linear| l.bias().cloned().expect("NGP layers have biases");
        let (b0, b1, b2, b3) = (
            bias(&self.density[0]),
            bias(&self.density[1]),
            bias(&self.color[1]),
            bias(&self.color[2]),
        );
        let wg = self.color[0].weight().narrow(1, 0, GEO_FEATURES)?;
        let (w0, w1) = (self.density[0].weight(), self.density[1].weight());
        let (w2, w3) = (self.color[1].weight(), self.color[2].weight());
        let layers = MlpLayers {
            w0,
            b0: &b0,
            w1,
            b1: &b1,
            wg: &wg,
            w2,
            b2: &b2,
            w3,
            b3: &b3,
        };
        Ok(mlp_forward(enc, per_ray, (ray_index, rays), &layers)?)
    }

    /// σ from the raw density (the configured activation), 0 where `inside` is 0.
    fn activate(&self, raw: &Tensor, inside: &Tensor) -> Result<Tensor> {
        let sigma = match self.params.density_activation {
            DensityActivation::TruncExp => trunc_exp(raw)?,
            DensityActivation::Softplus => (raw.exp()? + 1.0)?.log()?,
        };
        Ok((sigma * inside)?)
    }

    /// Density `(N, S, 1)` and colour `(N, S, 3)` at `points` `(N, S, 3)` of rays with unit
    /// `directions` `(N, 3)` from training images `camera_index` `(N,)` u32 (`None`: rays of
    /// no training image).
    pub(crate) fn forward(
        &self,
        points: &Tensor,
        directions: &Tensor,
        camera_index: Option<&Tensor>,
    ) -> Result<FieldOutput> {
        FieldOutput::from_packed(points, |flat, (ray_index, _)| {
            self.forward_packed(flat, ray_index, directions, camera_index)
        })
    }

    /// Density `(M, 1)` and colour `(M, 3)` at `points` `(M, 3)` drawn from N rays:
    /// `ray_index` `(M,)` u32 names each sample's ray in `directions` `(N, 3)` and, when
    /// given, in `camera_index` `(N,)` u32 (the training image of each ray).
    pub fn forward_packed(
        &self,
        points: &Tensor,
        ray_index: &Tensor,
        directions: &Tensor,
        camera_index: Option<&Tensor>,
    ) -> Result<(Tensor, Tensor)> {
        let (enc, inside) = self.encode(points)?;
        // The per-ray part only for the rays that have samples here (a segment of a skipping
        // render holds a few of them), the samples' ray indices renumbered to match.
        let rays = ray_index.to_vec1::<u32>()?;
        let (used, local) = rays_in_use(&rays, directions.dim(0)?)?;
        let out = if used.len() < directions.dim(0)? {
            let dev = directions.device();
            let n_used = used.len();
            let used = Tensor::from_vec(used, n_used, dev)?;
            let directions = directions.index_select(&used, 0)?;
            let cameras = camera_index.map(|c| c.index_select(&used, 0)).transpose()?;
            let local_t = Tensor::from_vec(local.clone(), rays.len(), dev)?;
            let per_ray = self.per_ray(&directions, cameras.as_ref())?;
            self.mlps(&enc, &per_ray, (&local_t, &local))?
        } else {
            let per_ray = self.per_ray(directions, camera_index)?;
            self.mlps(&enc, &per_ray, (ray_index, &rays))?
        };
        let sigma = self.activate(&out.narrow(1, 0, 1)?, &inside)?;
        Ok((sigma, out.narrow(1, 1, 3)?.contiguous()?))
    }

    /// Density alone at `points` `(M, 3)`: `(M, 1)` (what the occupancy grid probes).
    pub(crate) fn density(&self, points: &Tensor) -> Result<Tensor> {
        Ok(self.geometry(points)?.0)
    }

    /// The same model with parameters detached from the autograd graph, for rendering.
    pub(crate) fn detached(&self) -> Self {
        let detach = |l: &Linear| Linear::new(l.weight().detach(), l.bias().map(|b| b.detach()));
        Self {
            params: self.params.clone(),
            grid: self.grid,
            table: self.table.detach(),
            density: self.density.clone().map(|l| detach(&l)),
            color: self.color.clone().map(|l| detach(&l)),
            appearance: self.appearance.as_ref().map(Appearance::detached),
            gradient: None,
        }
    }
}

/// The rays among `n` that samples on rays `rays` `(M,)` use, in increasing order, and each
/// sample's ray as an index into them `(M,)`; an error for a ray index `≥ n`. One pass over
/// the samples and one over the rays, in place of a sort and a binary search per sample.
fn rays_in_use(rays: &[u32], n: usize) -> Result<(Vec<u32>, Vec<u32>)> {
    let mut position = vec![u32::MAX; n];
    for &r in rays {
        *position
            .get_mut(r as usize)
            .ok_or_else(|| anyhow::anyhow!("sample on ray {r}, but there are {n} rays"))? = 0;
    }
    let mut used = Vec::new();
    for (r, p) in position.iter_mut().enumerate() {
        if *p == 0 {
            *p = used.len() as u32;
            used.push(r as u32);
        }
    }
    let local = rays.iter().map(|&r| position[r as usize]).collect();
    Ok((used, local))
}

/// An NGP model as a field.
#[derive(Debug, Clone)]
pub struct NgpField {
    /// The model.
    pub model: Ngp,
    /// `(N,)` u32: the training image of each ray of the batch this field renders
    /// ([`Field::for_cameras`]); `None`: rays of no training image.
    pub camera_index: Option<Tensor>,
}

impl Field for NgpField {
    fn evaluate(
        &self,
        samples: &RaySamples,
        _deltas: &Tensor,
        directions: &Tensor,
    ) -> Result<FieldOutput> {
        self.model
            .forward(&samples.points, directions, self.camera_index.as_ref())
    }

    fn for_cameras(&self, camera_index: &Tensor) -> Result<Option<Box<dyn Field + '_>>> {
        if self.model.appearance.is_none() {
            return Ok(None);
        }
        Ok(Some(Box::new(NgpField {
            camera_index: Some(camera_index.clone()),
            ..self.clone()
        })))
    }

    fn density(&self, points: &Tensor) -> Result<Tensor> {
        self.model.density(points)
    }

    fn fast_paths(&self) -> Option<&dyn FieldFastPaths> {
        Some(self)
    }
}

impl FieldFastPaths for NgpField {
    fn supports_packed(&self) -> bool {
        true
    }

    fn evaluate_packed(
        &self,
        points: &Tensor,
        ray_index: &Tensor,
        directions: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        self.model
            .forward_packed(points, ray_index, directions, self.camera_index.as_ref())
    }

    fn max_samples_per_chunk(&self) -> usize {
        // Evaluated samples at once: a chunk's rays times a segment's 16 samples when samples
        // are skipped. The fused kernels keep only a few floats a sample between ops (the
        // encoding's 32 the most), so 2^19 (32,768 rays a chunk, ~64 MB) costs little memory,
        // and each segment's field call is large enough to keep every thread busy, where
        // smaller chunks made many small calls and slower frames (docs/hash-grid.md#rendering).
        1 << 19
    }
}

/// The name of the hash table among an NGP model's parameters.
pub const TABLE: &str = "encoding.table";

/// An NGP model with its parameters, being trained or rendered.
pub struct NgpState {
    /// The model's variables by name (`encoding.table`, `density_mlp.*`, `color_mlp.*`).
    pub varmap: VarMap,
    /// The model, built on `varmap`.
    pub model: Ngp,
    /// The table gradient the fused encoding leaves for the sparse optimiser.
    pub gradient: Arc<TableGradient>,
}

impl NgpState {
    /// A freshly initialised model, reproducible from `seed`: the table U(−1e‑4, 1e‑4)
    /// (instant-ngp), every linear layer's weight and bias U(−1/√fan_in, 1/√fan_in)
    /// (PyTorch's default), drawn in name order.
    pub fn seeded(params: &NgpParams, seed: u64, device: &Device) -> Result<Self> {
        let varmap = VarMap::new();
        let gradient = Arc::new(TableGradient::new(&params.grid()));
        let model = Ngp::new(params, VarBuilder::from_varmap(&varmap, DType::F32, device))?
            .with_table_gradient(gradient.clone());
        let bound = |name: &str, shapes: &_| match name {
            TABLE => 1e-4,
            crate::appearance::EMBEDDING => crate::appearance::EMBEDDING_INIT,
            _ => linear_init_bound(name, shapes),
        };
        seed_uniform(&varmap, seed, bound, device)?;
        Ok(Self {
            varmap,
            model,
            gradient,
        })
    }
}

impl FieldSpec for NgpParams {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn seeded(&self, seed: u64, device: &Device) -> Result<Box<dyn TrainableField>> {
        Ok(Box::new(NgpState::seeded(self, seed, device)?))
    }

    fn for_training_images(&self, images: usize) -> Option<Arc<dyn FieldSpec>> {
        self.appearance()?;
        Some(Arc::new(NgpParams {
            appearance_images: images,
            ..self.clone()
        }))
    }
}

impl TrainableField for NgpState {
    fn kind(&self) -> &'static str {
        KIND
    }

    /// The fused kernels on host buffers (`Ngp::density_values`) where they run, else the
    /// render field's density.
    fn density(&self, points: &Tensor) -> Result<Tensor> {
        if !nerf_kernels::use_fused(&self.model.table) {
            return self.model.detached().density(points);
        }
        let values = points
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        let sigma = self.model.density_values(&values)?;
        Ok(Tensor::from_vec(
            sigma,
            (values.len() / 3, 1),
            points.device(),
        )?)
    }

    fn layout(&self) -> Option<String> {
        let g = &self.model.grid;
        let NgpParams {
            aabb,
            density_activation,
            contraction,
            ..
        } = &self.model.params;
        Some(format!(
            "hash grid of {} levels x {} features, 2^{} rows a level, resolution {} to {}; \
             box {aabb:?}; contraction {contraction:?}; density {density_activation:?}",
            g.n_levels, g.n_features, g.log2_table_size, g.base_resolution, g.max_resolution
        ))
    }

    fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    fn training_field(&self, _density_noise: f64) -> BoxedField {
        Box::new(NgpField {
            model: self.model.clone(),
            camera_index: None,
        })
    }

    fn render_field(&self) -> BoxedField {
        Box::new(NgpField {
            model: self.model.detached(),
            camera_index: None,
        })
    }

    /// Dense Adam on the MLPs and sparse Adam on the hash table, both with instant-ngp's
    /// β₂ = 0.99 and ε = 1e‑15 (rows whose gradient is exactly zero are left alone, values
    /// and moments, as tiny-cuda-nn's Adam leaves zero-gradient parameters).
    fn param_groups(&self) -> ParamGroups {
        let (table, dense): (Vec<_>, Vec<_>) = named_vars(&self.varmap)
            .into_iter()
            .partition(|(n, _)| n == TABLE);
        let sparse_rows = table
            .into_iter()
            .map(|(name, var)| {
                let sink = (self.gradient.clone(), self.model.grid);
                SparseRowsGroup::instant_ngp(name, var, Some(sink))
            })
            .collect();
        ParamGroups {
            dense: DenseGroup {
                vars: dense,
                beta2: 0.99,
                eps: 1e-15,
            },
            sparse_rows,
        }
    }

    fn fast_paths(&self) -> Option<&dyn TrainingFastPaths> {
        Some(self)
    }
}

impl TrainingFastPaths for NgpState {
    fn fused_gradients(&self, batch: &FusedBatch) -> Result<Option<FusedGradients>> {
        if !self.model.has_fused_step() {
            return Ok(None);
        }
        Ok(Some(self.model.fused_gradients(batch)?))
    }
}

/// A small field for tests: 4 levels of 2 features, 2^8 rows a level, resolutions 4 to 32,
/// over `[-1.5, 1.5]³`, trunc_exp, no contraction, no appearance.
#[cfg(any(test, feature = "test-support"))]
pub fn small_test_params() -> NgpParams {
    NgpParams {
        n_levels: 4,
        n_features_per_level: 2,
        log2_hashmap_size: 8,
        base_resolution: 4.0,
        max_resolution: Some(32.0),
        aabb: [[-1.5; 3], [1.5; 3]],
        density_activation: DensityActivation::TruncExp,
        contraction: nerf_core::contraction::Contraction::None,
        appearance_dim: 0,
        appearance_images: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use candle_nn::VarMap;
    use nerf_core::contraction::Contraction;
    use nerf_kernels::test_support::abs_sum;

    /// `Σ |∂loss/∂table|`: whether a backward pass reached the hash table.
    fn table_gradient_size(grads: &candle_core::backprop::GradStore, model: &Ngp) -> f32 {
        abs_sum(grads.get(model.table()).expect("a table gradient"))
    }

    #[test]
    fn rays_in_use_are_sorted_and_renumbered() {
        let (used, local) = rays_in_use(&[5, 2, 5, 7, 2], 8).unwrap();
        assert_eq!(used, [2, 5, 7]);
        assert_eq!(local, [1, 0, 1, 2, 0]);
        let (used, local) = rays_in_use(&[], 3).unwrap();
        assert!(used.is_empty() && local.is_empty());
        let e = rays_in_use(&[1, 3], 3).unwrap_err().to_string();
        assert!(e.contains("ray 3") && e.contains("3 rays"), "{e}");
    }

    #[test]
    fn trunc_exp_value_is_exact_and_gradient_is_clamped() {
        let x = Var::new(&[0.5f32, 20.0, -3.0], &Device::Cpu).unwrap();
        let y = trunc_exp(&x).unwrap();
        let v = y.to_vec1::<f32>().unwrap();
        let g = y.sum_all().unwrap().backward().unwrap();
        let g = g.get(&x).unwrap().to_vec1::<f32>().unwrap();
        for (i, x) in [0.5f32, 20.0, -3.0].into_iter().enumerate() {
            assert!((v[i] / x.exp() - 1.0).abs() < 1e-5, "value at {x}");
            let want = x.min(TRUNC_EXP_MAX as f32).exp();
            assert!(
                (g[i] / want - 1.0).abs() < 1e-5,
                "gradient at {x}: {}",
                g[i]
            );
        }
    }

    /// A model of `params` on the CPU, with its variables.
    fn model_of(params: &NgpParams) -> (VarMap, Ngp) {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let model = Ngp::new(params, vb).unwrap();
        (varmap, model)
    }

    #[test]
    fn field_shapes_ranges_packing_and_box() {
        let dev = Device::Cpu;
        let (varmap, model) = model_of(&small_test_params());
        let points = Tensor::rand(-2f32, 2.0, (5, 7, 3), &dev).unwrap();
        let dirs = Tensor::randn(0f32, 1.0, (5, 3), &dev).unwrap();
        let dirs = dirs.broadcast_div(&dirs.sqr().unwrap().sum_keepdim(1).unwrap().sqrt().unwrap());
        let dirs = dirs.unwrap();
        let out = model.forward(&points, &dirs, None).unwrap();
        assert_eq!(out.density.dims(), &[5, 7, 1]);
        assert_eq!(out.feature.dims(), &[5, 7, 3]);
        let flat = points.reshape((35, 3)).unwrap();
        let ray_index = Tensor::from_vec((0..35u32).map(|i| i / 7).collect(), 35, &dev).unwrap();
        let (sigma, colour) = model
            .forward_packed(&flat, &ray_index, &dirs, None)
            .unwrap();
        let diff = |a: &Tensor, b: &Tensor| {
            nerf_core::compare::max_abs_difference(
                &a.flatten_all().unwrap(),
                &b.flatten_all().unwrap(),
            )
            .unwrap()
        };
        assert!(diff(&sigma, &out.density) < 1e-6);
        assert!(diff(&colour, &out.feature) < 1e-6);
        let p = flat.to_vec2::<f32>().unwrap();
        let s = sigma.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        for (p, s) in p.iter().zip(&s) {
            let inside = p.iter().all(|v| v.abs() <= 1.5);
            assert!(if inside { *s > 0.0 } else { *s == 0.0 }, "{p:?}: {s}");
        }
        // The gradient reaches the hash table through both MLPs.
        let loss = (out.density.sum_all().unwrap() + out.feature.sum_all().unwrap()).unwrap();
        let grads = loss.backward().unwrap();
        assert!(table_gradient_size(&grads, &model) > 0.0);
        let names: Vec<String> = varmap.data().lock().unwrap().keys().cloned().collect();
        assert_eq!(names.len(), 1 + 2 * 5, "{names:?}");
        assert!(names.contains(&"encoding.table".to_string()));
    }

    #[test]
    fn appearance_moves_colour_per_image_and_trains() {
        let dev = Device::Cpu;
        let (varmap, model) = model_of(&NgpParams {
            appearance_dim: 4,
            appearance_images: 3,
            ..small_test_params()
        });
        let points = Tensor::rand(-1f32, 1.0, (6, 3), &dev).unwrap();
        let ray_index = Tensor::new(&[0u32, 0, 1, 1, 2, 2], &dev).unwrap();
        let dirs = Tensor::new(&[[0f32, 0.0, 1.0]; 3], &dev).unwrap();
        let colour = |cameras: &[u32]| {
            let c = Tensor::new(cameras, &dev).unwrap();
            model
                .forward_packed(&points, &ray_index, &dirs, Some(&c))
                .unwrap()
                .1
        };
        // The same points seen from other images get other colours; density is untouched.
        let a = colour(&[0, 0, 0])
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let b = colour(&[1, 2, 0])
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert_eq!(a[12..], b[12..], "rays 2 (image 0 both times) agree");
        assert!(a[..12].iter().zip(&b[..12]).any(|(x, y)| x != y));
        // Rays of no image take the mean vector's term, one row for all of them.
        let (_, mean) = model
            .forward_packed(&points, &ray_index, &dirs, None)
            .unwrap();
        let app = model.appearance.as_ref().unwrap();
        let term = app.per_ray(None).unwrap();
        assert_eq!(term.dims(), &[1, HIDDEN]);
        assert_eq!(mean.dims(), &[6, 3]);
        // The loss reaches the per-image vectors, only those of the images in the batch.
        let loss = colour(&[0, 2, 2]).sum_all().unwrap();
        let grads = loss.backward().unwrap();
        let vars = varmap.data().lock().unwrap();
        let e = vars.get(crate::appearance::EMBEDDING).unwrap();
        let g = grads.get(e.as_tensor()).unwrap().to_vec2::<f32>().unwrap();
        let size = |row: &[f32]| row.iter().map(|v| v.abs()).sum::<f32>();
        assert!(size(&g[0]) > 0.0 && size(&g[2]) > 0.0);
        assert_eq!(size(&g[1]), 0.0);
    }

    #[test]
    fn contracted_field_covers_all_space_and_trains_through_the_contraction() {
        let dev = Device::Cpu;
        let params = NgpParams {
            aabb: [[-2.0; 3], [2.0; 3]],
            contraction: Contraction::LInf,
            ..small_test_params()
        };
        let (_, model) = model_of(&params);
        // Far points only: outside the unit cube, some hundreds of units away.
        let far = Tensor::new(
            &[[3.0f32, 0.5, -1.0], [-40.0, 2.0, 7.0], [0.0, 900.0, -100.0]],
            &dev,
        )
        .unwrap();
        let sigma = model.density(&far).unwrap();
        let s = sigma.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(s.iter().all(|&v| v > 0.0), "{s:?}");
        // The same model without contraction holds them outside its box: zero density.
        let boxed = Ngp {
            params: NgpParams {
                contraction: Contraction::None,
                ..params.clone()
            },
            ..model.clone()
        };
        let s = boxed.density(&far).unwrap().flatten_all().unwrap();
        assert!(s.to_vec1::<f32>().unwrap().iter().all(|&v| v == 0.0));
        // The contracted points are encoded where the f64 contraction puts them: the
        // encoding of the far points equals the boxed model's encoding of their contraction.
        let contracted: Vec<f32> = far
            .to_vec2::<f32>()
            .unwrap()
            .iter()
            .flat_map(|p| {
                Contraction::LInf
                    .contract([p[0], p[1], p[2]].map(f64::from))
                    .map(|v| v as f32)
            })
            .collect();
        let contracted = Tensor::from_vec(contracted, (3, 3), &dev).unwrap();
        let a = model.encode(&far).unwrap().0;
        let b = boxed.encode(&contracted).unwrap().0;
        let diff = nerf_core::compare::max_abs_difference(&a, &b).unwrap();
        assert!(diff < 1e-6, "{diff}");
        // Gradients reach the hash table from far samples.
        let grads = sigma.sum_all().unwrap().backward().unwrap();
        assert!(table_gradient_size(&grads, &model) > 0.0);
    }
}
