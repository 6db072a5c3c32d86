//! Fused CPU kernels, each with its backward pass and its tensor-op twin.

pub mod bias;
pub mod composite;
pub mod storage;
pub mod trunk;
