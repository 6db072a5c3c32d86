//! `nerf-field`: the fields `nerf` renders and trains: SDF volumes ([`sdf`]), the homework's
//! NeRF MLP ([`nerf`]) and the hash-grid (Instant-NGP-class) field ([`ngp`]), each kind's
//! config section beside it (`*_config.rs`), the training seam every kind implements
//! ([`trainable`]), and the one list of kinds a config can name ([`registry`]).
//!
//! The `nerf` facade re-exports this crate as `nerf::field`.

#![warn(missing_docs)]

pub mod appearance;
pub mod field_config;
pub mod fused_step;
pub mod nerf;
pub mod nerf_config;
pub mod ngp;
pub mod ngp_config;
pub mod registry;
pub mod sdf;
pub mod sdf_config;
pub mod spherical_harmonics;
pub mod trainable;

// The renderer's tests on the crate's own fields live here, beside the fields, so that the
// render layer's files name no concrete field.
#[cfg(test)]
mod renderer_tests;
#[cfg(test)]
mod skipping_tests;
#[cfg(test)]
mod view_tests;
