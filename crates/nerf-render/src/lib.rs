//! `nerf-render`: the rendering stage of `nerf`: samplers (stratified, coarse-to-fine,
//! disparity), the [`field::Field`] trait a field implements to be rendered, the chunked
//! volume renderer, the occupancy grid and empty-space skipping, and [`view::render_view`],
//! which renders one camera's image through a field, a sampler and a renderer.
//!
//! The `nerf` facade re-exports this crate as `nerf::render`.

#![warn(missing_docs)]

pub mod bands;
pub(crate) mod disparity_sampler;
pub mod field;
pub mod hierarchical;
pub mod occupancy;
pub mod occupied_field;
pub mod ray_sampler;
pub mod renderer;
pub mod sampler;
pub mod sampler_kind;
pub mod sampler_registry;
pub mod skipping;
pub mod view;
