//! Evaluation: PSNR over a dataset split, and the float64 reference renderer.

pub mod evaluate;
pub mod protocol;
pub mod reference;
