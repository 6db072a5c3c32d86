//! `nerf-train`: the training stage of `nerf`: the Adam optimiser (dense, and sparse for hash
//! tables), the model of any field kind with its optimiser ([`model`]), one training step
//! ([`step`]) and the loop over a dataset ([`fit`]), camera refinement, the run's schedules,
//! and the SDF volume fit ([`fit_sdf`]).
//!
//! The `nerf` facade re-exports this crate as `nerf::train`.

#![warn(missing_docs)]

pub mod adam;
pub mod camera_refinement;
pub mod fit;
pub mod fit_sdf;
pub mod model;
pub mod schedule;
pub(crate) mod sparse_adam;
pub mod step;

#[cfg(test)]
mod fused_step_tests;
