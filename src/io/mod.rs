//! Files: images, plots, datasets, checkpoints and PyTorch import, from the three crates that
//! hold them (`nerf-files`, `nerf-scene`, `nerf-checkpoint`); every output written by the one
//! rule of [`output`].

pub use nerf_checkpoint::{checkpoint, checkpoint_file, parameter_shapes, torch};
pub use nerf_files::{bounded_read, decode_budget, images, npy, output, ply, progress};
pub use nerf_scene::{camera_path, camera_truth, colmap, dataset};
