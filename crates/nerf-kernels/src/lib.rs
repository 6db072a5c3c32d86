//! `nerf-kernels`: the fused CPU kernels of `nerf`'s pipeline. Each op sits in one file with its backward pass (or none, where nothing
//! it reads is ever trained), its tensor-op twin, and a test that holds the two equal forward
//! and backward. This crate's root is the one place that decides which of the two runs:
//!
//! * [`KernelChoice::Fused`] (the default) runs a fused kernel where one exists: on the CPU,
//!   for f32 data. Everywhere else — another device, another dtype — the twin runs.
//! * [`KernelChoice::Generic`] always runs the tensor-op twins (the `nerf --kernels generic`
//!   option; on the CPU it stands in, in tests, for a device without fused kernels).
//!
//! The choice is process-wide ([`set_kernel_choice`]); [`with_kernel_choice`] overrides it on
//! the calling thread for a closure, which is what tests comparing the two paths use.
//!
//! The `nerf` facade re-exports this crate as `nerf::kernels`.

#![warn(missing_docs)]

use std::cell::Cell;
use std::sync::atomic::{AtomicU8, Ordering};

use candle_core::{DType, Tensor};

pub mod bias;
pub mod composite;
pub mod cpu_dispatch;
pub mod cpu_kernel;
pub mod distortion_loss;
pub(crate) mod fastexp;
pub mod gemm;
pub mod harmonic;
pub mod mlp_block;
pub mod nerf_mlp;
pub(crate) mod ray_distortion;
pub mod sample_points;
pub(crate) mod sdf_point;
pub(crate) mod sdf_ray;
pub mod sdf_render;
pub mod sdf_volume;
pub(crate) mod sdf_volume_grad;
pub mod sparse_adam;
pub mod storage;
#[cfg(any(test, feature = "test-support"))]
pub mod test_support;

/// Which implementation of the fused ops runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KernelChoice {
    /// Fused CPU kernels where they exist (CPU, f32); the tensor-op twins elsewhere.
    #[default]
    Fused,
    /// Always the tensor-op twins.
    Generic,
}

static PROCESS_CHOICE: AtomicU8 = AtomicU8::new(0);

thread_local! {
    static THREAD_CHOICE: Cell<Option<KernelChoice>> = const { Cell::new(None) };
}

/// Sets the process-wide choice (the CLI's `--kernels`).
pub fn set_kernel_choice(choice: KernelChoice) {
    PROCESS_CHOICE.store(choice as u8, Ordering::Relaxed);
}

/// The choice in force on this thread.
pub(crate) fn kernel_choice() -> KernelChoice {
    THREAD_CHOICE.with(|c| c.get()).unwrap_or_else(|| {
        match PROCESS_CHOICE.load(Ordering::Relaxed) {
            0 => KernelChoice::Fused,
            _ => KernelChoice::Generic,
        }
    })
}

/// Runs `f` with `choice` in force on the calling thread (restored afterwards, also on error).
pub fn with_kernel_choice<T>(choice: KernelChoice, f: impl FnOnce() -> T) -> T {
    struct Restore(Option<KernelChoice>);
    impl Drop for Restore {
        fn drop(&mut self) {
            THREAD_CHOICE.with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(THREAD_CHOICE.with(|c| c.replace(Some(choice))));
    f()
}

/// Whether a fused CPU kernel runs on `t`'s data: fused kernels are chosen, `t` (any shape) is on
/// the CPU and holds f32.
pub fn use_fused(t: &Tensor) -> bool {
    kernel_choice() == KernelChoice::Fused && t.device().is_cpu() && t.dtype() == DType::F32
}

/// Whether autograd tracks `t` (any shape; a variable, or computed from one): an op without a
/// backward pass must not run on such an input, or the gradient would silently stop there.
pub(crate) fn needs_grad(t: &Tensor) -> bool {
    t.track_op()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thread_override_is_scoped() {
        let t = Tensor::zeros(2, DType::F32, &candle_core::Device::Cpu).unwrap();
        assert!(use_fused(&t));
        with_kernel_choice(KernelChoice::Generic, || {
            assert!(!use_fused(&t));
        });
        assert!(use_fused(&t));
        assert!(!use_fused(&t.to_dtype(DType::F64).unwrap()));
    }
}
