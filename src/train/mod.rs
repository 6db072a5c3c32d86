//! Training: the Adam optimiser (dense, and sparse for hash tables), the model state, one step
//! and the loop.

pub mod adam;
pub mod fit;
pub mod sparse_adam;
pub mod state;
pub mod step;
