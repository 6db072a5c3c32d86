//! The fields: SDF volumes, the NeRF MLP and the hash-grid (Instant-NGP-class) field.

pub mod nerf;
pub mod ngp;

pub mod sdf;
pub mod trainable;
