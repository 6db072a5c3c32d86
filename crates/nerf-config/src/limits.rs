//! Upper limits on sizes, so that a typo such as an extra zero is a one-line error naming the
//! key instead of an allocation that exhausts memory. Each is far above what the homework's
//! scenes use (400×400 images, 128 samples per ray, 1024-ray batches, 20 poses).

/// Largest image width or height.
pub const IMAGE_SIDE: usize = 4096;
/// Most samples per ray.
pub(crate) const PTS_PER_RAY: usize = 16384;
/// Most surround poses.
pub const POSES: usize = 3600;
/// Most pixels over all surround frames (every frame is kept in memory for the GIF).
pub const FRAME_PIXELS: usize = 1 << 26;
/// Most samples in one training batch (`batch_size × n_pts_per_ray`), all held with
/// their activations for the backward pass.
pub(crate) const BATCH_SAMPLES: usize = 1 << 21;
/// Most samples drawn in one step whose rays adapt to `training.samples_per_step`: with an
/// occupancy grid or early termination only the evaluated ones hold activations, a drawn
/// one costs its depth and a grid test.
pub(crate) const DRAWN_SAMPLES: usize = 1 << 23;
// The NeRF's own sizes (harmonics, widths, depth) are bounded beside its config
// (`nerf_field::nerf_config`); the command's export and render sizes in its own `limits.rs`.
