//! `nerf`: differentiable volume rendering and Neural Radiance Fields on Candle, following the
//! conventions of the PyTorch + pytorch3d NeRF homework.
//!
//! The pipeline, one layer a folder, each importing only the layers before it:
//!
//! * [`core`]: pytorch3d cameras, the homework's pixel grid and rays, the volume-rendering
//!   maths, SDF maths, marching cubes, images and metrics;
//! * [`io`]: images, PLY meshes and point clouds, plots, datasets and captures, nerfstudio
//!   camera paths, checkpoints, PyTorch import, progress;
//! * [`kernels`]: fused CPU ops, each with its backward pass and tensor-op twin, and the one
//!   switch between them ([`KernelChoice`]);
//! * [`render`]: the stratified sampler, the [`Field`] trait, the volume renderer, occupancy
//!   grid and empty-space skipping;
//! * [`field`]: the fields — SDF volumes ([`SdfField`]), the NeRF MLP ([`NerfField`]) and
//!   the hash grid — each kind's config beside it, and the one list of kinds a config can
//!   name ([`field::registry`]);
//! * [`train`]: Adam, the NeRF state, one training step and the loop;
//! * [`eval`]: PSNR over a dataset split, and the float64 reference renderer;
//! * [`config`]: the homework's config files (YAML) as data, turned into the plain
//!   parameters above.
//!
//! Each boundary a program crosses returns a typed error it can match on: [`CameraError`]
//! (a camera that cannot be right), [`CheckpointError`] (a checkpoint missing, malformed or
//! of other sizes), [`DatasetError`] (a dataset or capture folder) and [`ConfigError`] (a
//! config file or override); every other failure is an `anyhow::Error` whose text is one line.
//!
//! The `nerf` command's jobs (render, camera paths, train, eval, bench, report, export,
//! process and the `nerf view` web viewer) are not part of the library: they are the
//! `nerf-cli` package (`apps/nerf/src/`), which calls the library as any user would.
//!
//! ```no_run
//! use nerf::{render_view, Pipeline, SdfField, SdfVolume, Sdf, StratifiedSampler, VolumeRenderer};
//! # fn main() -> anyhow::Result<()> {
//! let device = candle_core::Device::Cpu;
//! let volume = SdfVolume {
//!     sdf: Sdf::Box { center: [0.0; 3], side_lengths: [1.75; 3] },
//!     alpha: 1.0,
//!     beta: 0.05,
//!     rainbow: true,
//!     feature: [1.0; 3],
//! };
//! let field = SdfField::fixed(&volume, &device)?;
//! let camera: nerf::Camera = nerf::surround_cameras(3.0, 20, glam::DVec3::Y, 1.0)[0].into();
//! let sampler = StratifiedSampler::new(64, 0.0, 5.0)?;
//! let renderer = VolumeRenderer::new(32768, false)?;
//! let view = render_view(&Pipeline::new(&field, &sampler, &renderer), &camera, (256, 256), &device)?;
//! nerf::io::images::write_png(std::path::Path::new("box.png"), &view.color)?;
//! # Ok(())
//! # }
//! ```

#![warn(missing_docs)]

/// The Candle crates this library is built on, at the versions it uses: a library user
/// writes `nerf::candle_core::Tensor` and needs no matching dependency of their own.
pub use candle_core;
pub use candle_nn;
/// The vector maths of the camera API (`glam::DVec3` for eye, target and up).
pub use glam;

/// The homework's config files and the built-in ones: the `nerf-config` crate.
pub use nerf_config as config;
/// The maths every stage shares: the `nerf-core` crate.
pub use nerf_core as core;
/// PSNR over a split and the float64 reference renderer: the `nerf-eval` crate.
pub use nerf_eval as eval;
/// The fields (SDF volume, NeRF MLP, hash grid) and their registry: the `nerf-field` crate.
pub use nerf_field as field;
pub mod io;
/// The hash grid: encoding, fused MLPs, box mapping, direction encoding: the `nerf-hash-grid` crate.
pub use nerf_hash_grid as hash_grid;
/// The fused CPU kernels and the switch between them and their twins: the `nerf-kernels` crate.
pub use nerf_kernels as kernels;
/// Samplers, the `Field` trait, the renderer and the occupancy grid: the `nerf-render` crate.
pub use nerf_render as render;
/// Adam, the model of any field kind, one training step and the loop: the `nerf-train` crate.
pub use nerf_train as train;

pub use crate::config::ConfigError;
pub use crate::core::allocator::{ensure_allocator_tuned, tune_allocator};
pub use crate::core::camera::CameraError;
pub use crate::core::camera::{
    camera_position_from_spherical_angles, look_at_view_transform, surround_cameras, Camera,
    PerspectiveCamera,
};

pub use crate::core::image::RgbImage;
pub use crate::core::rays::{pixel_grid, random_pixel_indices, Rays};
pub use crate::core::sdf::{Sdf, SdfVolume};
pub use crate::field::nerf::{Nerf, NerfField, NerfParams, NerfState};
pub use crate::field::sdf::{SdfField, SdfTrainable};
pub use crate::field::trainable::{named_vars, FieldSpec, TrainableField};
pub use crate::io::checkpoint::{CheckpointError, CheckpointInfo};
pub use crate::io::dataset::{Dataset, DatasetError, Split};
pub use crate::kernels::sdf_volume::{density_to_sigma, sdf_to_density};
pub use crate::kernels::{set_kernel_choice, with_kernel_choice, KernelChoice};
pub use crate::render::field::{Composited, Field, FieldOutput};
pub use crate::render::hierarchical::CoarseToFineSampler;
pub use crate::render::occupancy::{OccupancyGrid, OccupancyGridParams};
pub use crate::render::ray_sampler::RaySampler;
pub use crate::render::renderer::{RenderOutput, VolumeRenderer};
pub use crate::render::sampler::{RaySamples, StratifiedSampler};
pub use crate::render::view::{render_view, Pipeline, RenderSettings, RenderedView};
pub use crate::train::adam::Adam;
pub use crate::train::fit::{fit, Hooks, RunLimits, TrainPaths, TrainSettings};
pub use crate::train::model::{LoadedCheckpoint, Optimizer, TrainModel};
