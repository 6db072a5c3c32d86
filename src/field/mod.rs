//! The fields: SDF volumes, the NeRF MLP and the hash-grid (Instant-NGP-class) field.

pub mod appearance;
pub mod nerf;
pub mod ngp;

pub mod sdf;
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
