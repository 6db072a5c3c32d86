//! Files: images, plots, datasets, checkpoints and PyTorch import.

pub mod camera_path;
pub mod checkpoint;
pub mod checkpoint_file;
pub mod dataset;
pub mod images;
pub mod npy;
#[cfg(feature = "cli")]
pub mod plot;
pub mod ply;
pub mod progress;
pub mod torch;
pub mod torch_archive;
pub mod torch_save;
