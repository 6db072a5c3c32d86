//! `nerf-checkpoint`: a model's parameters and training state on disk: `nerf`'s own
//! safetensors checkpoints ([`checkpoint`], [`checkpoint_file`]), their typed error
//! ([`checkpoint_error`]), and the PyTorch side: `torch.save` archives read and written
//! ([`torch_archive`], [`torch_save`]) through a bounded pickle reader ([`pickle`]), and the
//! homework's checkpoints imported ([`torch`]).
//!
//! The `nerf` facade re-exports these modules under `nerf::io`.

#![warn(missing_docs)]

pub mod checkpoint;
pub mod checkpoint_error;
pub mod checkpoint_file;
pub mod parameter_shapes;
pub mod pickle;
pub mod torch;
pub mod torch_archive;
pub mod torch_save;
