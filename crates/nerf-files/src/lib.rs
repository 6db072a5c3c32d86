//! `nerf-files`: reading and writing files the way every stage of `nerf` does. Every output
//! goes through the one rule of [`output`] (written beside its target, then renamed; never
//! over a symlink or a device); PNG and GIF images ([`images`]), `.npy` arrays ([`npy`]) and
//! PLY meshes and point clouds ([`ply`]); reads bounded in size ([`bounded_read`]) and in
//! decoded pixels ([`decode_budget`]); and progress on stderr ([`progress`]).
//!
//! The `nerf` facade re-exports these modules under `nerf::io`.

#![warn(missing_docs)]

pub mod bounded_read;
pub mod decode_budget;
pub mod images;
pub mod npy;
pub mod output;
pub mod ply;
pub mod progress;
#[cfg(any(test, feature = "test-support"))]
pub mod test_files;
