//! Training: the Adam optimiser, the model state, one step and the loop.

pub mod adam;
pub mod fit;
pub mod state;
pub mod step;
