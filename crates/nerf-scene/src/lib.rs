//! `nerf-scene`: scene data for `nerf`: the datasets and captures a model is trained on
//! ([`dataset`]: NeRF-synthetic, nerfstudio and instant-ngp `transforms.json`, COLMAP, LLFF,
//! the Middlebury and Strecha layouts, with their masks, normalisation and held-out split),
//! COLMAP's sparse models ([`colmap`]), surveyed camera truth ([`camera_truth`]) and
//! nerfstudio camera paths ([`camera_path`]).
//!
//! The `nerf` facade re-exports these modules under `nerf::io`.

#![warn(missing_docs)]

pub mod camera_path;
pub mod camera_truth;
pub mod colmap;
pub mod dataset;
