//! The fields: SDF volumes and the NeRF MLP.

pub mod nerf;
pub mod sdf;
