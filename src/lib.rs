//! `nerf`: differentiable volume rendering and Neural Radiance Fields on Candle, following the
//! conventions of the PyTorch + pytorch3d NeRF homework.
//!
//! The pipeline: [`camera`] → [`rays`] → [`sampler`] → [`field`] ([`sdf`] volumes) →
//! [`renderer`] → images.

pub mod camera;
pub mod field;
pub mod rays;
pub mod renderer;
pub mod sampler;
pub mod sdf;
