//! Sampling, the volume-rendering maths, the renderer, occupancy grid and skipping.

pub mod bands;
pub mod depth_points;
pub mod disparity_sampler;
pub mod field;
pub mod hierarchical;
pub mod occupancy;
pub mod pointcloud;
pub mod ray_sampler;
pub mod renderer;
pub mod sampler;
pub mod sampler_kind;
pub mod sampler_registry;
pub mod skipping;
pub mod surface;
pub mod view;
