//! `nerf-core`: the maths every stage of `nerf` shares, and nothing else of it: pytorch3d
//! cameras and the COLMAP camera models, the homework's pixel grid and rays, the
//! volume-rendering maths, SDF maths, marching cubes, images and image metrics.
//!
//! The other crates of the workspace build on it; the `nerf` facade re-exports it as
//! `nerf::core`, so `nerf::core::rays::Rays` and `nerf_core::rays::Rays` are one type.

#![warn(missing_docs)]

pub mod allocator;
pub mod camera;
pub mod compare;
pub mod contraction;
pub mod error_chain;
pub mod image;
pub mod key_checks;
pub mod lens;
pub mod marching_cubes;
pub(crate) mod marching_tables;
pub mod metrics;
pub(crate) mod pixel_grid;
pub mod rays;
pub mod registry;
pub mod sdf;
pub mod term;
pub mod truncate;
pub mod volume;
