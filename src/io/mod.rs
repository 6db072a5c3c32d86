//! Files: images, plots, datasets, checkpoints and PyTorch import.

pub mod camera_path;
pub mod checkpoint;
pub mod dataset;
pub mod images;
#[cfg(feature = "cli")]
pub mod plot;
pub mod ply;
pub mod progress;
pub mod torch;
