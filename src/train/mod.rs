//! Training: the Adam optimiser (dense, and sparse for hash tables), the model state, one step
//! and the loop, and the SDF volume fit.

pub mod adam;
pub mod camera_refinement;
pub mod fit;
pub mod fit_sdf;
pub mod model;
pub mod schedule;
pub mod sparse_adam;
pub mod step;

#[cfg(test)]
mod fused_step_tests;
