//! The seam for a training step without an autograd graph over the samples: what the trainer
//! hands a field kind that has one ([`crate::trainable::TrainingFastPaths::fused_gradients`])
//! and what it gets back. The hash-grid field's is [`crate::ngp`]'s `fused_step`.

use candle_core::backprop::GradStore;
use candle_core::Tensor;

use nerf_core::rays::Rays;
use nerf_render::occupancy::OccupancyGrid;
use nerf_render::skipping::SampleCounts;

/// One training step's rays and what they are scored against: the loss is the mean squared
/// error of each ray's colour, composited onto its `background`, against its `target`.
pub struct FusedBatch<'a> {
    /// N rays (each with its training image, when the field learns per-image appearance).
    pub rays: &'a Rays,
    /// The rays' sample depths `(N, S, 1)`, increasing, or `(1, S, 1)` shared by all rays.
    pub lengths: &'a Tensor,
    /// Target colours `(N, 3)`, row-major.
    pub target: &'a [f32],
    /// The colour behind each ray `(N, 3)`, row-major: a ray's colour is
    /// `colour + (1 − opacity) · background`.
    pub background: &'a [f32],
    /// The grid whose empty cells are skipped, if any.
    pub occupancy: Option<&'a OccupancyGrid>,
    /// Transmittance below which a ray stops being evaluated (0 = off).
    pub early_termination: f64,
}

/// What a fused step's forward and backward passes give.
pub struct FusedGradients {
    /// The mean squared colour error of the batch (over its `3·N` values).
    pub mse: f64,
    /// Samples drawn, tested and evaluated.
    pub samples: SampleCounts,
    /// The gradient of the MSE for each trained variable, as autograd would give it (a
    /// table whose optimiser takes its gradient from a sink gets it there instead).
    pub grads: GradStore,
}
