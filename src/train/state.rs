//! A NeRF being trained or rendered: its variables, the model and its occupancy grid.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use rand::SeedableRng;

use crate::field::nerf::{Nerf, NerfField, NerfParams};
use crate::io::checkpoint::{self, CheckpointInfo};
use crate::io::checkpoint_file;
use crate::render::occupancy::{grid_for_checkpoint, OccupancyGrid, OccupancyGridParams};

/// A NeRF with its parameters.
pub struct NerfState {
    /// The model's variables by PyTorch name.
    pub varmap: VarMap,
    /// The model, built on `varmap`.
    pub model: Nerf,
    /// Where the model can have density, when the config uses an occupancy grid.
    pub occupancy: Option<OccupancyGrid>,
}

impl NerfState {
    /// A freshly initialised model: PyTorch's default `nn.Linear` init, U(−1/√fan_in,
    /// 1/√fan_in) for weights and biases, drawn from a generator seeded with `seed` (parameters
    /// in name order), so runs are reproducible.
    pub fn new(params: &NerfParams, device: &Device) -> Result<Self> {
        Self::seeded(params, 0, device)
    }

    /// [`NerfState::new`] with an explicit seed.
    pub fn seeded(params: &NerfParams, seed: u64, device: &Device) -> Result<Self> {
        use rand::Rng;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
        let model = Nerf::new(params, vb)?;
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        for (name, var) in named_vars(&varmap) {
            // fan_in is the weight's second dimension; a bias shares its layer's weight fan_in.
            let weight_name = name
                .strip_suffix(".bias")
                .map(|p| format!("{p}.weight"))
                .unwrap_or(name.clone());
            let fan_in = varmap.data().lock().expect("varmap lock")[&weight_name].dims()[1];
            let bound = 1.0 / (fan_in as f64).sqrt();
            let values: Vec<f32> = (0..var.elem_count())
                .map(|_| rng.random_range(-bound..bound) as f32)
                .collect();
            var.set(&Tensor::from_vec(values, var.shape(), device)?)?;
        }
        Ok(Self {
            varmap,
            model,
            occupancy: None,
        })
    }

    /// A model loaded from a checkpoint of either format, ours or PyTorch's (names and shapes
    /// checked).
    pub fn from_checkpoint(
        params: &NerfParams,
        path: &Path,
        device: &Device,
    ) -> Result<(Self, CheckpointInfo)> {
        let (tensors, info) = checkpoint_file::load(path, params, device)?;
        let state = Self::new(params, device)?;
        checkpoint::load_model_into(&state.varmap, &tensors, params, path)?;
        Ok((state, info))
    }

    /// A trained model for rendering: weights from the checkpoint file at `path` (ours or a
    /// PyTorch file, told apart by content), and, with `grid`, an occupancy grid (the one
    /// saved in the checkpoint, or one built from the model).
    pub fn load(
        params: &NerfParams,
        grid: Option<&OccupancyGridParams>,
        path: &Path,
        device: &Device,
    ) -> Result<(Self, CheckpointInfo)> {
        let (tensors, info) = checkpoint_file::load(path, params, device)?;
        let mut state = Self::new(params, device)?;
        checkpoint::load_model_into(&state.varmap, &tensors, params, path)?;
        if let Some(grid) = grid {
            let model = state.model.detached();
            let density = |p: &Tensor| model.density(p);
            state.occupancy = Some(grid_for_checkpoint(grid, &tensors, &density, device)?);
        }
        Ok((state, info))
    }

    /// The field for training: the model's weights as variables (gradients reach them) with
    /// `density_noise`, and the occupancy grid if there is one.
    pub fn training_field(&self, density_noise: f64) -> NerfField {
        NerfField {
            model: self.model.clone(),
            density_noise,
            occupancy: self.occupancy.clone().map(Arc::new),
        }
    }

    /// The field for rendering: detached weights (no gradient graph), no density noise, and
    /// the occupancy grid if there is one.
    pub fn field(&self) -> NerfField {
        NerfField {
            model: self.model.detached(),
            density_noise: 0.0,
            occupancy: self.occupancy.clone().map(Arc::new),
        }
    }
}

/// Named parameters for the optimiser, in a fixed order.
pub fn named_vars(varmap: &VarMap) -> Vec<(String, candle_core::Var)> {
    let data = varmap.data().lock().expect("varmap lock");
    let mut v: Vec<_> = data
        .iter()
        .map(|(k, var)| (k.clone(), var.clone()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}
