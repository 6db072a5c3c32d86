//! The model a training run optimises, of any field kind (a [`TrainableField`]), with its
//! occupancy grid, and its optimiser: Adam on the dense parameters and sparse Adam on the
//! tables whose rows each step touches ([`ParamGroups`]).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use candle_core::backprop::GradStore;
use candle_core::{Device, Tensor};
use candle_nn::VarMap;

use crate::adam::Adam;
use crate::camera_refinement::CameraRefinement;
use crate::sparse_adam::SparseAdam;
use nerf_checkpoint::checkpoint::CheckpointError;
use nerf_checkpoint::checkpoint::{self, CheckpointInfo};
use nerf_checkpoint::checkpoint_file;
use nerf_field::trainable::{BoxedField, FieldSpec, ParamGroups, SparseRowsGroup, TrainableField};
use nerf_hash_grid::hash_grid::{HashGridParams, TableGradient};
use nerf_render::occupancy::{
    grid_for_checkpoint, OccupancyGrid, OccupancyGridParams, CHECKPOINT_KEY,
};
use nerf_render::occupied_field::OccupiedField;

/// A model read from a checkpoint, with everything else the checkpoint holds.
pub struct LoadedCheckpoint {
    /// The model, its parameters set from the checkpoint (no occupancy grid yet).
    pub model: TrainModel,
    /// Every tensor of the checkpoint by name: the parameters, the optimiser's state
    /// (`adam.*`) and, when saved, the occupancy grid.
    pub tensors: HashMap<String, Tensor>,
    /// What the checkpoint says of training progress.
    pub info: CheckpointInfo,
}

/// The model being trained or rendered: a field of any kind and, when the config uses one, the
/// occupancy grid that marks where it can have density.
pub struct TrainModel {
    /// The model's parameters and fields.
    pub field: Box<dyn TrainableField>,
    /// Where the model can have density, when the config uses an occupancy grid.
    pub occupancy: Option<OccupancyGrid>,
}

/// [`CheckpointError::Metadata`] (key [`checkpoint::FIELD_LAYOUT_KEY`]) when the checkpoint at
/// `path` stored a layout ([`TrainableField::layout`]) other than `field`'s: the same shapes
/// read another way (a hash grid of other resolutions) would render garbage. A checkpoint
/// without one (older, or a PyTorch file) is taken as it is.
fn check_layout(
    field: &dyn TrainableField,
    info: &CheckpointInfo,
    path: &Path,
) -> Result<(), CheckpointError> {
    let (Some(saved), Some(wanted)) = (&info.field_layout, field.layout()) else {
        return Ok(());
    };
    if *saved == wanted {
        return Ok(());
    }
    let message = format!(
        "checkpoint {} holds a model of another layout: it was trained as {saved}, the config \
         makes {wanted}; set the config's implicit_function to the checkpoint's",
        path.display()
    );
    Err(CheckpointError::metadata(
        path,
        checkpoint::FIELD_LAYOUT_KEY,
        message,
    ))
}

impl TrainModel {
    /// A model without an occupancy grid.
    pub(crate) fn new(field: Box<dyn TrainableField>) -> Self {
        Self {
            field,
            occupancy: None,
        }
    }

    /// A freshly initialised model of `spec`, reproducible from `seed`.
    pub fn seeded(spec: &dyn FieldSpec, seed: u64, device: &Device) -> Result<Self> {
        Ok(Self::new(spec.seeded(seed, device)?))
    }

    /// The model of `spec` with the weights of the checkpoint at `path` (ours or a PyTorch
    /// file, told apart by content; names and shapes checked), the checkpoint's tensors
    /// (optimiser state, grid) and what it says of progress. Errors: those of
    /// [`checkpoint_file::load`], and [`CheckpointError::MissingParameter`] or
    /// [`CheckpointError::Shape`] for a checkpoint of another model.
    pub fn from_checkpoint(
        spec: &dyn FieldSpec,
        path: &Path,
        device: &Device,
    ) -> Result<LoadedCheckpoint, CheckpointError> {
        let mut field = spec.seeded(0, device).map_err(CheckpointError::Other)?;
        let mut expected = field.parameter_shapes();
        let (tensors, info) = checkpoint_file::load(path, &expected, device)?;
        // Per-image parameters are sized by the images the checkpoint was trained on.
        let images = tensors
            .get(nerf_field::appearance::EMBEDDING)
            .and_then(|t| t.dims().first().copied());
        if let Some(sized) = images.and_then(|n| spec.for_training_images(n)) {
            field = sized.seeded(0, device).map_err(CheckpointError::Other)?;
            expected = field.parameter_shapes();
        }
        // Names and shapes are checked there (`checkpoint_file::check_parameters`); its
        // typed error comes back out of the anyhow chain.
        nerf_field::trainable::load_parameters(
            field.varmap(),
            &expected,
            &tensors,
            field.kind(),
            path,
        )
        .map_err(CheckpointError::from_anyhow)?;
        check_layout(field.as_ref(), &info, path)?;
        Ok(LoadedCheckpoint {
            model: Self::new(field),
            tensors,
            info,
        })
    }

    /// A trained model for rendering: weights from the checkpoint at `path` and, with `grid`,
    /// an occupancy grid (the one saved in the checkpoint, or one built from the model). Errors
    /// as [`TrainModel::from_checkpoint`]'s; one building the grid is [`CheckpointError::Other`].
    pub fn load(
        spec: &dyn FieldSpec,
        grid: Option<&OccupancyGridParams>,
        path: &Path,
        device: &Device,
    ) -> Result<(Self, CheckpointInfo), CheckpointError> {
        let LoadedCheckpoint {
            mut model,
            tensors,
            info,
        } = Self::from_checkpoint(spec, path, device)?;
        if let Some(grid) = grid {
            let field = &model.field;
            let density = |p: &Tensor| field.density(p);
            let built = grid_for_checkpoint(grid, &tensors, &density, device);
            model.occupancy = Some(built.map_err(CheckpointError::Other)?);
        }
        Ok((model, info))
    }

    /// The model's variables.
    pub(crate) fn varmap(&self) -> &VarMap {
        self.field.varmap()
    }

    /// The field to train: parameters as variables (gradients reach them); `density_noise`
    /// for the kinds that add noise to their raw density. Rendered through the occupancy
    /// grid, when there is one.
    pub fn training_field(&self, density_noise: f64) -> BoxedField {
        self.through_grid(self.field.training_field(density_noise))
    }

    /// The field to render or score: detached parameters, no density noise, rendered
    /// through the occupancy grid when there is one.
    pub fn render_field(&self) -> BoxedField {
        self.through_grid(self.field.render_field())
    }

    /// `field` paired with a copy of the occupancy grid, when there is one.
    fn through_grid(&self, field: BoxedField) -> BoxedField {
        match &self.occupancy {
            Some(grid) => Box::new(OccupiedField {
                field,
                grid: Arc::new(grid.clone()),
            }),
            None => field,
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
        let field = &self.field;
        if let Some(grid) = &mut self.occupancy {
            grid.update(&|p| field.density(p), warmup, decay, rng, device)?;
        }
        Ok(())
    }

    /// Every parameter by name, and the occupancy grid under [`CHECKPOINT_KEY`].
    pub(crate) fn tensors(&self, device: &Device) -> Result<Vec<(String, Tensor)>> {
        let mut tensors = checkpoint::model_tensors(self.varmap());
        if let Some(grid) = &self.occupancy {
            tensors.push((CHECKPOINT_KEY.to_string(), grid.to_tensor(device)?));
        }
        Ok(tensors)
    }
}

/// A sparse table's optimiser and, when a fused op leaves its gradient outside autograd,
/// where to take it from.
struct SparseTable {
    adam: SparseAdam,
    sink: Option<(Arc<TableGradient>, HashGridParams)>,
}

/// The optimiser of a [`TrainModel`], as its [`ParamGroups`] say: PyTorch's Adam on the dense
/// parameters and `SparseAdam` on each sparsely updated table.
pub struct Optimizer {
    /// Adam on the dense parameters; its step count is the run's.
    pub dense: Adam,
    tables: Vec<SparseTable>,
    /// The training cameras' corrections and their own optimiser, when refined.
    pub cameras: Option<CameraRefinement>,
    initial_lr: f64,
}

impl Optimizer {
    /// The optimiser for `model` at learning rate `lr`.
    pub fn new(model: &TrainModel, lr: f64) -> Result<Self> {
        let ParamGroups { dense, sparse_rows } = model.field.param_groups();
        let adam = Adam::for_group(dense, lr)?;
        let tables = sparse_rows
            .into_iter()
            .map(|group: SparseRowsGroup| {
                let mut sparse = SparseAdam::new(&group.name, group.var, lr)?;
                sparse.beta2 = group.beta2;
                sparse.eps = group.eps;
                Ok(SparseTable {
                    adam: sparse,
                    sink: group.sink,
                })
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            dense: adam,
            tables,
            cameras: None,
            initial_lr: lr,
        })
    }

    /// Steps taken.
    pub(crate) fn step_count(&self) -> u64 {
        self.dense.step
    }

    /// The learning rate now.
    pub(crate) fn lr(&self) -> f64 {
        self.dense.lr
    }

    /// Sets the learning rate of every parameter.
    pub(crate) fn set_lr(&mut self, lr: f64) {
        self.dense.lr = lr;
        for t in &mut self.tables {
            t.adam.lr = lr;
        }
        if let Some(c) = &mut self.cameras {
            c.set_lr_factor(lr / self.initial_lr);
        }
    }

    /// One update from `grads`.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        self.dense.step(grads)?;
        for SparseTable { adam, sink } in &self.tables {
            // A generic encoding's gradient comes through autograd, a fused one's through
            // the sink.
            if let Some(g) = grads.get(adam.var().as_tensor()) {
                adam.step_nonzero(g)?;
            }
            if let Some((sink, grid)) = sink {
                sink.take(grid, |rows, values| adam.step_rows(values, rows))?;
            }
        }
        if let Some(c) = &mut self.cameras {
            c.step(grads)?;
        }
        Ok(())
    }

    /// The optimiser's state by name (see [`Adam::state_tensors`] and
    /// [`SparseAdam::state_tensors`]), and the camera corrections with their state when
    /// refined ([`CameraRefinement::state_tensors`]).
    pub(crate) fn state_tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let mut out = self.dense.state_tensors();
        for t in &self.tables {
            out.extend(t.adam.state_tensors()?);
        }
        if let Some(c) = &self.cameras {
            out.extend(c.state_tensors()?);
        }
        Ok(out)
    }

    /// Restores the state of [`Optimizer::state_tensors`] after `step` steps.
    pub(crate) fn load_state(
        &mut self,
        tensors: &HashMap<String, Tensor>,
        step: u64,
    ) -> Result<()> {
        self.dense.load_state(tensors, step)?;
        for t in &self.tables {
            t.adam.load_state(tensors)?;
        }
        Ok(())
    }
}
