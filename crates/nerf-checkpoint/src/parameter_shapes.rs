//! What a checkpoint of a model must hold, named and shaped: the one description that field
//! kinds give (`nerf::field::trainable::FieldSpec::parameter_shapes`) and that the
//! checkpoint readers check a file against.

/// Every parameter's name and shape, in the order checkpoints write them (for the NeRF MLP,
/// PyTorch's module order, which the homework's optimiser state is indexed by).
pub type ParameterShapes = Vec<(String, Vec<usize>)>;
