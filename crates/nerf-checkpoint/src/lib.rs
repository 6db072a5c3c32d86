//! `nerf-checkpoint`: a model's parameters and training state on disk: `nerf`'s own
//! safetensors checkpoints ([`checkpoint`], [`checkpoint_file`]), their typed error
//! ([`checkpoint::CheckpointError`]), and the PyTorch side: the homework's checkpoints read and
//! imported, and written back as `torch.save` archives ([`torch`]), through this crate's own
//! bounded pickle reader (`pickle.rs`, `torch_archive.rs`, `torch_save.rs`: internal).
//!
//! The `nerf` facade re-exports these modules under `nerf::io`.

#![warn(missing_docs)]

pub mod checkpoint;
mod checkpoint_error;
pub mod checkpoint_file;
pub mod parameter_shapes;
pub(crate) mod pickle;
pub mod torch;
pub(crate) mod torch_archive;
pub(crate) mod torch_save;

#[cfg(test)]
mod hostile_torch_tests;
