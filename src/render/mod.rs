//! Sampling, the volume-rendering maths, the renderer, occupancy grid and skipping.

pub mod field;
pub mod occupancy;
pub mod pointcloud;
pub mod renderer;
pub mod sampler;
pub mod skipping;
pub mod view;
