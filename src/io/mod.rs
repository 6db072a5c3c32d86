//! Files: images, plots, datasets, checkpoints and PyTorch import; every output written by
//! the one rule of [`output`].

pub mod bounded_read;
pub mod camera_path;
pub mod camera_truth;
pub mod checkpoint;
pub mod checkpoint_error;
pub mod checkpoint_file;
pub mod colmap;
pub mod dataset;
pub mod decode_budget;
pub mod images;
pub mod npy;
pub mod output;
pub mod parameter_shapes;
pub mod pickle;
#[cfg(feature = "cli")]
pub mod plot;
pub mod ply;
pub mod progress;
#[cfg(test)]
pub(crate) mod test_files;
pub mod torch;
pub mod torch_archive;
pub mod torch_save;
