//! Training: the Adam optimiser, the NeRF state, one step and the loop, and the SDF volume fit.

pub mod adam;
pub mod fit;
pub mod fit_sdf;
pub mod state;
pub mod step;
