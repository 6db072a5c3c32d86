//! Core: cameras, rays and the pixel grid, and small shared maths. Imports nothing else of the crate.

pub mod allocator;
pub mod camera;
pub mod camera_alignment;
pub mod camera_checks;
pub mod camera_colmap;
pub mod camera_consensus;
pub mod camera_error;
pub mod camera_model;
pub mod compare;
pub mod contraction;
pub mod distortion;
pub mod distortion_loss;
pub(crate) mod error_chain;
pub mod fastexp;
pub mod frame_camera;
pub mod frame_selection;
pub mod image;
pub mod key_checks;
pub mod marching_cubes;
pub mod marching_tables;
pub mod metrics;
pub mod pixel_grid;
pub mod rays;
pub mod sdf;
pub mod term;
pub mod volume;
