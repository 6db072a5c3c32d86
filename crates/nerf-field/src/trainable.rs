//! The seam between a field kind and everything that trains, saves, loads or configures it.
//!
//! A field kind (the NeRF MLP, the hash grid, or one a library user writes) is two types:
//!
//! * its sizes, a [`FieldSpec`]: the kind's name and how to make a freshly seeded model;
//! * the model, a [`TrainableField`]: its parameters by name (what checkpoints hold), how the
//!   optimiser treats them ([`ParamGroups`]), and the [`Field`] it renders and trains through.
//!
//! The trainer (`nerf::train`), checkpoints (`nerf::io`) and the command line only ever hold
//! a `dyn FieldSpec` / `dyn TrainableField`; the kinds a config can name are listed once, in
//! `crate::registry`.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::VarMap;
use rand::{Rng, SeedableRng};

use nerf_checkpoint::parameter_shapes::ParameterShapes;
use nerf_hash_grid::hash_grid::{HashGridParams, TableGradient};
use nerf_render::field::Field;

/// A field that can be handed to other threads (the viewer renders on a worker).
pub type BoxedField = Box<dyn Field + Send + Sync>;

/// The sizes of a field kind: enough to make a model of it.
pub trait FieldSpec: std::fmt::Debug + Send + Sync {
    /// The kind's name, as a config's `implicit_function.type` writes it.
    fn kind(&self) -> &'static str;

    /// A freshly initialised model, reproducible from `seed`.
    fn seeded(&self, seed: u64, device: &Device) -> Result<Box<dyn TrainableField>>;

    /// The same sizes with parameters for `images` training images (the training set's
    /// size, or the rows of the per-image table a checkpoint holds); `None` (the default)
    /// for a kind without per-image parameters.
    fn for_training_images(&self, _images: usize) -> Option<Arc<dyn FieldSpec>> {
        None
    }

    /// Every parameter's name and shape in checkpoint order (what a checkpoint of this model
    /// must hold). The default makes a model on the CPU and asks it.
    fn parameter_shapes(&self) -> Result<ParameterShapes> {
        Ok(self.seeded(0, &Device::Cpu)?.parameter_shapes())
    }
}

/// A model being trained or rendered: its parameters and the fields built on them.
pub trait TrainableField: Send + Sync {
    /// The kind's name (see [`FieldSpec::kind`]).
    fn kind(&self) -> &'static str;

    /// The model's variables by name.
    fn varmap(&self) -> &VarMap;

    /// Every parameter's name and shape in checkpoint order. The default: the variables
    /// sorted by name.
    fn parameter_shapes(&self) -> ParameterShapes {
        named_vars(self.varmap())
            .into_iter()
            .map(|(name, var)| (name, var.dims().to_vec()))
            .collect()
    }

    /// The field to train through: the parameters as variables, so gradients reach them.
    /// `density_noise` is the standard deviation of the noise the NeRF MLP adds to its raw
    /// density; kinds without such noise ignore it. (An occupancy grid is not the field's:
    /// the trainer pairs the two, `nerf_render::occupied_field::OccupiedField`.)
    fn training_field(&self, density_noise: f64) -> BoxedField;

    /// The field to render or score: detached parameters (no gradient graph), no noise.
    fn render_field(&self) -> BoxedField;

    /// Density σ `(M, 1)` at points `(M, 3)`, detached (the occupancy grid's probe). The
    /// default asks the render field ([`Field::density`]).
    fn density(&self, points: &Tensor) -> Result<Tensor> {
        self.render_field().density(points)
    }

    /// After each optimiser step: holds the parameters inside the range where the field is
    /// defined (the SDF volume clamps α, β and its sizes). The default does nothing.
    fn constrain(&self) -> Result<()> {
        Ok(())
    }

    /// The kind's fused training kernels, when it has them; `None` (the default) trains
    /// through the renderer and autograd alone.
    fn fast_paths(&self) -> Option<&dyn TrainingFastPaths> {
        None
    }

    /// What the parameters' names and shapes do not say about how they are read (a hash
    /// grid's resolutions, the box it covers), as one line: a checkpoint stores it and a model
    /// whose layout differs refuses to load it, where it would otherwise load and render
    /// garbage. `None` (the default) for a kind whose shapes say it all.
    fn layout(&self) -> Option<String> {
        None
    }

    /// How the optimiser treats the parameters. The default: PyTorch's Adam on all of them.
    fn param_groups(&self) -> ParamGroups {
        ParamGroups {
            dense: DenseGroup::pytorch(named_vars(self.varmap())),
            sparse_rows: Vec::new(),
        }
    }
}

/// The trainer's fast paths into a field kind: how the crate's SDF volume and hash grid hand
/// it a fused render-and-loss kernel or a training step without an autograd graph over the
/// samples. An inside seam between the trainer and the kernels, not part of what a new kind
/// implements; a kind offers it through [`TrainableField::fast_paths`], and every method has
/// the default of a kind without the kernel.
pub trait TrainingFastPaths {
    /// The mean squared colour error of `rays` (N) rendered at `lengths` `(N, S, 1)` against
    /// `target` `(N, 3)` (composited on white when `white_background`), from a fused
    /// render-and-loss kernel, differentiable in the parameters; `None` (the default) when the
    /// kind has none for these inputs, and the trainer renders and takes the error itself.
    fn fused_mse(
        &self,
        _rays: &nerf_core::rays::Rays,
        _lengths: &Tensor,
        _target: &Tensor,
        _white_background: bool,
    ) -> Result<Option<Tensor>> {
        Ok(None)
    }

    /// One training step's gradients without an autograd graph over the samples
    /// ([`crate::fused_step`]); `None` (the default) when the kind has no such step for
    /// these inputs, and the trainer renders and differentiates through autograd.
    fn fused_gradients(
        &self,
        _batch: &crate::fused_step::FusedBatch,
    ) -> Result<Option<crate::fused_step::FusedGradients>> {
        Ok(None)
    }
}

/// Dense parameters, optimised by Adam with these constants.
pub struct DenseGroup {
    /// The parameters by name.
    pub vars: Vec<(String, Var)>,
    /// Adam's β₂.
    pub beta2: f64,
    /// Adam's ε.
    pub eps: f64,
}

impl DenseGroup {
    /// `vars` under PyTorch's Adam defaults (β₂ = 0.999, ε = 1e‑8).
    pub fn pytorch(vars: Vec<(String, Var)>) -> Self {
        Self {
            vars,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// A table of which each step touches a few rows: sparse Adam updates only those rows (rows
/// whose gradient is exactly zero keep their values and moments).
pub struct SparseRowsGroup {
    /// The table's name.
    pub name: String,
    /// The table `(rows, features)`.
    pub var: Var,
    /// Adam's β₂.
    pub beta2: f64,
    /// Adam's ε.
    pub eps: f64,
    /// Where a fused encoding leaves the table's row gradient instead of autograd, and the
    /// grid's shape; `None` when the gradient always comes through autograd.
    pub sink: Option<(Arc<TableGradient>, HashGridParams)>,
}

impl SparseRowsGroup {
    /// The table `var`, saved under `name`, with instant-ngp's Adam constants (β₂ = 0.99,
    /// ε = 1e‑15); `sink` as [`SparseRowsGroup::sink`].
    pub fn instant_ngp(
        name: String,
        var: Var,
        sink: Option<(Arc<TableGradient>, HashGridParams)>,
    ) -> Self {
        Self {
            name,
            var,
            beta2: 0.99,
            eps: 1e-15,
            sink,
        }
    }
}

/// How an optimiser treats a model's parameters: every parameter in exactly one group.
pub struct ParamGroups {
    /// The dense parameters; their Adam's step count is the run's.
    pub dense: DenseGroup,
    /// The sparsely updated tables.
    pub sparse_rows: Vec<SparseRowsGroup>,
}

/// Named variables of `varmap`, sorted by name.
pub fn named_vars(varmap: &VarMap) -> Vec<(String, Var)> {
    let data = varmap.data().lock().expect("varmap lock");
    let mut v: Vec<_> = data
        .iter()
        .map(|(k, var)| (k.clone(), var.clone()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// Sets every variable of `varmap` to U(−b, b) with `b = bound(name, shapes)`, drawn from a
/// generator seeded with `seed`, variables in name order and elements in order (so a model
/// is reproducible from its seed). `shapes`: every variable's shape by name.
pub fn seed_uniform(
    varmap: &VarMap,
    seed: u64,
    bound: impl Fn(&str, &HashMap<String, Vec<usize>>) -> f64,
    device: &Device,
) -> Result<()> {
    let vars = named_vars(varmap);
    let shapes: HashMap<String, Vec<usize>> = vars
        .iter()
        .map(|(n, v)| (n.clone(), v.dims().to_vec()))
        .collect();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    for (name, var) in vars {
        let b = bound(&name, &shapes);
        let values: Vec<f32> = (0..var.elem_count())
            .map(|_| rng.random_range(-b..b) as f32)
            .collect();
        var.set(&Tensor::from_vec(values, var.shape(), device)?)?;
    }
    Ok(())
}

/// PyTorch's default `nn.Linear` bound for the parameter `name`: 1/√fan_in, where fan_in is
/// the second dimension of the layer's weight (a bias shares its weight's).
pub(crate) fn linear_init_bound(name: &str, shapes: &HashMap<String, Vec<usize>>) -> f64 {
    let weight = name
        .strip_suffix(".bias")
        .map(|p| format!("{p}.weight"))
        .unwrap_or_else(|| name.to_string());
    1.0 / (shapes[&weight][1] as f64).sqrt()
}

/// Copies `tensors` into `varmap`, checking every name and shape of `expected` (the error
/// names the tensor and both shapes; `kind` says what the checkpoint should have been).
pub fn load_parameters(
    varmap: &VarMap,
    expected: &ParameterShapes,
    tensors: &HashMap<String, Tensor>,
    kind: &str,
    origin: &Path,
) -> Result<()> {
    nerf_checkpoint::checkpoint_file::check_parameters(tensors, expected, kind, origin)?;
    let data = varmap.data().lock().expect("varmap lock");
    for (name, _) in expected {
        let (Some(t), Some(var)) = (tensors.get(name), data.get(name)) else {
            bail!("model has no parameter {name}");
        };
        var.set(&t.to_dtype(DType::F32)?.to_device(var.device())?)?;
    }
    Ok(())
}
