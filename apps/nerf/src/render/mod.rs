//! `nerf render` and the scenes every command renders: a config or checkpoint loaded as a field,
//! its cameras, and camera paths.

pub mod path_frames;
mod pointcloud;
pub mod scene;
pub mod scene_frame;
