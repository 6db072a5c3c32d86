//! `nerf`: differentiable volume rendering and Neural Radiance Fields on Candle, following the
//! conventions of the PyTorch + pytorch3d NeRF homework.
//!
//! The pipeline: [`camera`] → [`rays`] → [`sampler`] → [`field`] ([`sdf`] volumes) →
//! [`renderer`] → images.

pub mod app;
pub mod core;
pub mod eval;
pub mod field;
pub mod io;
pub mod kernels;
pub mod render;
pub mod train;

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
