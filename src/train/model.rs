//! The model a training run optimises, of either kind — the homework's NeRF MLP or the
//! hash-grid field — and its optimiser: dense Adam for the MLP weights and, for the hash
//! table, the sparse Adam that updates only the rows a step touched.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use candle_core::backprop::GradStore;
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use rand::SeedableRng;

use crate::field::nerf::NerfParams;
use crate::field::ngp::{Ngp, NgpField, NgpParams};
use crate::io::checkpoint::{self, CheckpointInfo};
use crate::kernels::hash_grid::TableGradient;
use crate::render::field::Field;
use crate::render::occupancy::{OccupancyGrid, CHECKPOINT_KEY};
use crate::train::adam::Adam;
use crate::train::sparse_adam::SparseAdam;
use crate::train::state::{named_vars, NerfState};

/// The sizes of the model to train.
#[derive(Debug, Clone, PartialEq)]
pub enum ModelParams {
    /// The homework's NeRF MLP.
    Nerf(NerfParams),
    /// The hash-grid field.
    Ngp(NgpParams),
}

/// The name of the hash table among an NGP model's parameters.
pub const TABLE: &str = "encoding.table";

/// An NGP model with its parameters and occupancy grid.
pub struct NgpState {
    /// The model's variables by name (`encoding.table`, `density_mlp.*`, `color_mlp.*`).
    pub varmap: VarMap,
    /// The model, built on `varmap`.
    pub model: Ngp,
    /// Where the model can have density, when the config uses an occupancy grid.
    pub occupancy: Option<OccupancyGrid>,
    /// The table gradient the fused encoding leaves for the sparse optimiser.
    pub gradient: Arc<TableGradient>,
}

impl NgpState {
    /// A freshly initialised model, reproducible from `seed`: the table U(−1e‑4, 1e‑4)
    /// (instant-ngp), every linear layer's weight and bias U(−1/√fan_in, 1/√fan_in)
    /// (PyTorch's default), drawn in name order.
    pub fn seeded(params: &NgpParams, seed: u64, device: &Device) -> Result<Self> {
        use rand::Rng;
        let varmap = VarMap::new();
        let gradient = Arc::new(TableGradient::new(&params.grid));
        let model = Ngp::new(params, VarBuilder::from_varmap(&varmap, DType::F32, device))?
            .with_table_gradient(gradient.clone());
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let shapes: HashMap<String, Vec<usize>> = named_vars(&varmap)
            .into_iter()
            .map(|(n, v)| (n, v.dims().to_vec()))
            .collect();
        for (name, var) in named_vars(&varmap) {
            let bound = if name == TABLE {
                1e-4
            } else {
                let weight = name
                    .strip_suffix(".bias")
                    .map(|p| format!("{p}.weight"))
                    .unwrap_or(name.clone());
                1.0 / (shapes[&weight][1] as f64).sqrt()
            };
            let values: Vec<f32> = (0..var.elem_count())
                .map(|_| rng.random_range(-bound..bound) as f32)
                .collect();
            var.set(&Tensor::from_vec(values, var.shape(), device)?)?;
        }
        Ok(Self {
            varmap,
            model,
            occupancy: None,
            gradient,
        })
    }

    /// The model's parameters from `tensors` (names and shapes checked; any float dtype).
    fn load_weights(&self, tensors: &HashMap<String, Tensor>, origin: &Path) -> Result<()> {
        for (name, var) in named_vars(&self.varmap) {
            let Some(t) = tensors.get(&name) else {
                bail!(
                    "checkpoint {} lacks tensor {name} (is it an ngp checkpoint of this config's sizes?)",
                    origin.display()
                );
            };
            if t.dims() != var.dims() {
                bail!(
                    "checkpoint {} has {name} of shape {:?}, the config's ngp needs {:?}",
                    origin.display(),
                    t.dims(),
                    var.dims()
                );
            }
            var.set(&t.to_dtype(DType::F32)?.to_device(var.device())?)?;
        }
        Ok(())
    }
}

/// The model being trained.
pub enum TrainModel {
    /// The homework's NeRF MLP.
    Nerf(NerfState),
    /// The hash-grid field.
    Ngp(NgpState),
}

impl TrainModel {
    /// A freshly initialised model of `params`, reproducible from `seed`.
    pub fn seeded(params: &ModelParams, seed: u64, device: &Device) -> Result<Self> {
        Ok(match params {
            ModelParams::Nerf(p) => Self::Nerf(NerfState::seeded(p, seed, device)?),
            ModelParams::Ngp(p) => Self::Ngp(NgpState::seeded(p, seed, device)?),
        })
    }

    /// The model of `params` with the weights of the checkpoint at `path`, the checkpoint's
    /// tensors (optimizer state, grid) and what it says of progress.
    pub fn from_checkpoint(
        params: &ModelParams,
        path: &Path,
        device: &Device,
    ) -> Result<(Self, HashMap<String, Tensor>, CheckpointInfo)> {
        match params {
            ModelParams::Nerf(p) => {
                let (tensors, info) = crate::io::checkpoint_file::load(path, p, device)?;
                let state = NerfState::new(p, device)?;
                checkpoint::load_model_into(&state.varmap, &tensors, p, path)?;
                Ok((Self::Nerf(state), tensors, info))
            }
            ModelParams::Ngp(p) => {
                let (tensors, info) = checkpoint::load(path, device)?;
                let state = NgpState::seeded(p, 0, device)?;
                state.load_weights(&tensors, path)?;
                Ok((Self::Ngp(state), tensors, info))
            }
        }
    }

    /// The model's variables.
    pub fn varmap(&self) -> &VarMap {
        match self {
            Self::Nerf(s) => &s.varmap,
            Self::Ngp(s) => &s.varmap,
        }
    }

    /// The occupancy grid, if training keeps one.
    pub fn occupancy(&self) -> Option<&OccupancyGrid> {
        match self {
            Self::Nerf(s) => s.occupancy.as_ref(),
            Self::Ngp(s) => s.occupancy.as_ref(),
        }
    }

    /// The occupancy grid, to set or update.
    pub fn occupancy_mut(&mut self) -> &mut Option<OccupancyGrid> {
        match self {
            Self::Nerf(s) => &mut s.occupancy,
            Self::Ngp(s) => &mut s.occupancy,
        }
    }

    /// The field to train: parameters as variables (gradients reach them); `density_noise`
    /// applies to the NeRF MLP only.
    pub fn training_field(&self, density_noise: f64) -> Box<dyn Field> {
        match self {
            Self::Nerf(s) => Box::new(s.training_field(density_noise)),
            Self::Ngp(s) => Box::new(NgpField {
                model: s.model.clone(),
                occupancy: s.occupancy.clone().map(Arc::new),
            }),
        }
    }

    /// The field to render or score: detached parameters, no density noise.
    pub fn field(&self) -> Box<dyn Field> {
        match self {
            Self::Nerf(s) => Box::new(s.field()),
            Self::Ngp(s) => Box::new(NgpField {
                model: s.model.detached(),
                occupancy: s.occupancy.clone().map(Arc::new),
            }),
        }
    }

    /// Updates the occupancy grid (if any) from the current model's density; see
    /// [`OccupancyGrid::update`].
    pub fn update_grid(
        &mut self,
        warmup: bool,
        decay: f32,
        rng: &mut impl rand::Rng,
        device: &Device,
    ) -> Result<()> {
        match self {
            Self::Nerf(s) => {
                let model = s.model.detached();
                if let Some(grid) = &mut s.occupancy {
                    grid.update(&|p| model.density(p), warmup, decay, rng, device)?;
                }
            }
            Self::Ngp(s) => {
                let model = s.model.detached();
                if let Some(grid) = &mut s.occupancy {
                    grid.update(&|p| model.density(p), warmup, decay, rng, device)?;
                }
            }
        }
        Ok(())
    }

    /// Every parameter by name, and the occupancy grid under [`CHECKPOINT_KEY`].
    pub fn tensors(&self, device: &Device) -> Result<Vec<(String, Tensor)>> {
        let mut tensors = checkpoint::model_tensors(self.varmap());
        if let Some(grid) = self.occupancy() {
            tensors.push((CHECKPOINT_KEY.to_string(), grid.to_tensor(device)?));
        }
        Ok(tensors)
    }
}

/// The optimiser of a [`TrainModel`]: PyTorch's Adam on every dense parameter and, for an
/// NGP model, [`SparseAdam`] on the hash table (rows whose gradient is exactly zero are left
/// alone, values and moments, as tiny-cuda-nn's Adam leaves zero-gradient parameters; both
/// use instant-ngp's β₂ = 0.99 and ε = 1e‑15 there).
pub struct Optimizer {
    /// Adam on the dense parameters; its step count is the run's.
    pub dense: Adam,
    /// Sparse Adam on the hash table (NGP only).
    pub table: Option<SparseAdam>,
    /// Where the fused encoding leaves the table gradient (NGP only), and the grid's shape.
    table_gradient: Option<(
        Arc<TableGradient>,
        crate::kernels::hash_grid::HashGridParams,
    )>,
}

impl Optimizer {
    /// The optimiser for `model` at learning rate `lr`.
    pub fn new(model: &TrainModel, lr: f64) -> Result<Self> {
        let vars = named_vars(model.varmap());
        match model {
            TrainModel::Nerf(_) => Ok(Self {
                dense: Adam::new(vars, lr)?,
                table: None,
                table_gradient: None,
            }),
            TrainModel::Ngp(state) => {
                let (table, dense): (Vec<_>, Vec<_>) =
                    vars.into_iter().partition(|(n, _)| n == TABLE);
                let mut dense = Adam::new(dense, lr)?;
                dense.beta2 = 0.99;
                dense.eps = 1e-15;
                let (name, var) = table.into_iter().next().expect("an NGP model has a table");
                let mut sparse = SparseAdam::new(&name, var, lr)?;
                sparse.beta2 = 0.99;
                sparse.eps = 1e-15;
                Ok(Self {
                    dense,
                    table: Some(sparse),
                    table_gradient: Some((state.gradient.clone(), state.model.params.grid)),
                })
            }
        }
    }

    /// Steps taken.
    pub fn step_count(&self) -> u64 {
        self.dense.step
    }

    /// The learning rate now.
    pub fn lr(&self) -> f64 {
        self.dense.lr
    }

    /// Sets the learning rate of every parameter.
    pub fn set_lr(&mut self, lr: f64) {
        self.dense.lr = lr;
        if let Some(t) = &mut self.table {
            t.lr = lr;
        }
    }

    /// One update from `grads`.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        self.dense.step(grads)?;
        let Some(table) = &self.table else {
            return Ok(());
        };
        // The generic encoding's gradient comes through autograd, the fused one's through the
        // sink.
        if let Some(g) = grads.get(table.var().as_tensor()) {
            table.step_nonzero(g)?;
        }
        if let Some((sink, grid)) = &self.table_gradient {
            sink.take(grid, |rows, values| table.step_rows(values, rows))?;
        }
        Ok(())
    }

    /// The optimiser's state by name (see [`Adam::state_tensors`] and
    /// [`SparseAdam::state_tensors`]).
    pub fn state_tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let mut out = self.dense.state_tensors();
        if let Some(t) = &self.table {
            out.extend(t.state_tensors()?);
        }
        Ok(out)
    }

    /// Restores the state of [`Optimizer::state_tensors`] after `step` steps.
    pub fn load_state(&mut self, tensors: &HashMap<String, Tensor>, step: u64) -> Result<()> {
        self.dense.load_state(tensors, step)?;
        if let Some(t) = &self.table {
            t.load_state(tensors)?;
        }
        Ok(())
    }
}
