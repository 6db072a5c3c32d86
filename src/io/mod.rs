//! Files: images, plots, datasets, checkpoints and PyTorch import.

pub mod checkpoint;
pub mod checkpoint_file;
pub mod dataset;
pub mod images;
pub mod npy;
pub mod plot;
pub mod progress;
pub mod torch;
pub mod torch_archive;
pub mod torch_save;
