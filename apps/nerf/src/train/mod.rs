//! `nerf train` and `nerf targets`: a config's job (fit the box SDF, or train a NeRF) run with
//! the command's progress, signal handler and previews.

pub mod box_fit;
pub mod jobs;
pub mod nerf_run;
