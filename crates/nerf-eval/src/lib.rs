//! `nerf-eval`: evaluation for `nerf`: PSNR and SSIM over a dataset split under a stated
//! protocol ([`evaluate`], [`protocol`]), and the float64 reference renderer ([`reference`](mod@reference)).
//!
//! The `nerf` facade re-exports this crate as `nerf::eval`.

#![warn(missing_docs)]

pub mod evaluate;
pub mod protocol;
pub mod reference;
