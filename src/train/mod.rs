//! Training: the Adam optimiser and the NeRF training loop.

pub mod adam;
pub mod fit;
