//! `nerf-field`: the fields `nerf` renders and trains: SDF volumes ([`sdf`]), the homework's
//! NeRF MLP ([`nerf`]) and the hash-grid (Instant-NGP-class) field ([`ngp`]), each kind's
//! config section beside it (`*_config.rs`), the training seam every kind implements
//! ([`trainable`]), and the one list of kinds a config can name ([`registry`]).
//!
//! The `nerf` facade re-exports this crate as `nerf::field`.

#![warn(missing_docs)]

#[macro_use]
pub mod registry;

pub mod appearance;
pub mod field_config;
pub mod fused_step;
pub mod nerf;
pub mod ngp;
pub mod sdf;
pub mod trainable;

// The field kinds a config can name, in the order messages list them: each line declares the
// module that defines the kind's config and registers its `FieldKind`
// (`registry::FIELD_KINDS`). A new kind is its own file and one line here.
field_kinds! {
    sdf_config::SDF_VOLUME,
    nerf_config::NERF,
    ngp_config::NGP,
}

// The renderer's tests on the crate's own fields live here, beside the fields, so that the
// render layer's files name no concrete field.
#[cfg(test)]
mod renderer_tests;
#[cfg(test)]
mod skipping_tests;
#[cfg(test)]
mod view_tests;
