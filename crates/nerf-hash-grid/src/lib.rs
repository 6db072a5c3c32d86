//! `nerf-hash-grid`: the hash grid of `nerf`'s Instant-NGP-class field, in one home, as
//! tiny-cuda-nn is instant-ngp's. Each op is a fused CPU kernel with its backward pass, its
//! tensor-op twin and a test that holds the two equal, built on `nerf-kernels`' toolkit (the
//! [`nerf_kernels::cpu_kernel`] seam, the switch [`nerf_kernels::use_fused`], the dense
//! layers of [`nerf_kernels::mlp_block`]):
//!
//! * [`hash_grid`]: the multiresolution hash encoding, forward, and backward into a table
//!   gradient that lists the rows a step touched ([`hash_grid::TableGradient`]); the shape of
//!   the grid and its levels in `hash_level`, the vectorised inner loops in `hash_block`,
//!   the gradient with respect to the points (for camera refinement) in
//!   `hash_point_gradient`;
//! * [`ngp_mlp`]: the density and colour MLPs as one fused op;
//! * [`box_unit`]: points mapped from the scene's box to the grid's `[0, 1]³`;
//! * [`spherical_harmonics`]: the direction encoding of the colour MLP.
//!
//! The field built on them (parameters, config, its training step without autograd) is
//! `nerf_field::ngp`; sparse Adam, which any table field can use, is `nerf_train`'s. The
//! `nerf` facade re-exports this crate as `nerf::hash_grid`.

#![warn(missing_docs)]

pub mod box_unit;
#[cfg(test)]
mod encoding_f64;
pub(crate) mod hash_block;
pub mod hash_grid;
pub(crate) mod hash_level;
pub(crate) mod hash_point_gradient;
pub mod ngp_mlp;
pub mod spherical_harmonics;
