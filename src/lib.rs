//! `nerf`: differentiable volume rendering and Neural Radiance Fields on Candle, following the
//! conventions of the PyTorch + pytorch3d NeRF homework.
//!
//! The pipeline: [`camera`] → [`rays`] → [`sampler`] → [`field`] ([`sdf`] volumes) →
//! [`renderer`] → images.

pub mod bench;
pub mod camera;
pub mod compare;
pub mod composite;
pub mod config;
pub mod field;
pub mod images;
pub mod plot;
pub mod pointcloud;
pub mod rays;
pub mod renderer;
pub mod sampler;
pub mod scene;
pub mod sdf;
pub mod skipping;

/// For programs that use this library on the system allocator (the `nerf` binary uses mimalloc
/// instead, and its test binaries use glibc): tunes glibc's allocator for tensor work: tensors of many megabytes are allocated and freed
/// for every op, and by default glibc hands each back to the OS, so the next op pays page
/// faults to get it again (measured: about 40% of the box render's time). Raising the mmap and
/// trim thresholds keeps freed buffers for reuse. A no-op on other platforms.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; it is called before any threads start.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}
pub mod adam;
pub mod bias;
pub mod checkpoint;
pub mod dataset;
pub mod eval;
pub mod import;
pub mod mlp;
pub mod nerf_model;
pub mod occupancy;
pub mod reference;
pub mod report;
pub mod storage;
pub mod train;
