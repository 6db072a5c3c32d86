//! The fields: SDF volumes, the NeRF MLP and the hash-grid (Instant-NGP-class) field, each
//! kind's config beside it (`*_config.rs`), and the one list of kinds a config can name
//! ([`registry`]).

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
