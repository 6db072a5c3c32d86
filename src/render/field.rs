//! Fields: what the renderer queries at sample points.

use anyhow::Result;
use candle_core::Tensor;

use std::sync::Arc;

use crate::field::nerf::Nerf;
use crate::field::sdf::SdfVolume;
use crate::render::occupancy::OccupancyGrid;
use crate::render::sampler::RaySamples;

/// Volume density and feature (colour) at every sample.
#[derive(Debug, Clone)]
pub struct FieldOutput {
    /// `(N, S, 1)` volume density σ ≥ 0 (may be +∞ for an opaque sample).
    pub density: Tensor,
    /// `(N, S, 3)` colour.
    pub feature: Tensor,
}

/// The implicit functions the renderer can draw.
#[derive(Debug, Clone)]
pub enum Field {
    Sdf(SdfVolume),
    /// A NeRF; `density_noise` is the training-time noise added before its density ReLU
    /// (0 when rendering); `occupancy`, when present, marks where it can have density (the
    /// renderer skips samples elsewhere).
    Nerf {
        model: Nerf,
        density_noise: f64,
        occupancy: Option<Arc<OccupancyGrid>>,
    },
}

impl Field {
    /// The most samples (rays × points per ray) to evaluate at once. The renderer lowers its
    /// `chunk_size` to fit, which bounds memory without changing any output: a NeRF keeps
    /// activations of 128 floats per sample per layer (2^15 samples: 16 MiB each, small
    /// enough for the allocator to reuse instead of mapping fresh pages each time — the dense
    /// training step went from 1.45 s to 1.32 s against 2^18), an SDF volume a few floats
    /// (2^22 samples: about 250 MB over all of a chunk's tensors; the homework's box frame,
    /// 256² rays × 64 points, fits in one).
    pub fn max_samples_per_chunk(&self) -> usize {
        match self {
            Field::Sdf(_) => 1 << 22,
            Field::Nerf { .. } => 1 << 15,
        }
    }

    /// Evaluates the field at the samples of N rays.
    ///
    /// `samples`: points `(N, S, 3)`, lengths `(N, S, 1)`; `deltas`: `(N, S, 1)`;
    /// `directions`: `(N, 3)` unit ray directions. Returns density `(N, S, 1)` and
    /// feature `(N, S, 3)`.
    pub fn evaluate(
        &self,
        samples: &RaySamples,
        deltas: &Tensor,
        directions: &Tensor,
    ) -> Result<FieldOutput> {
        match self {
            Field::Sdf(volume) => volume.evaluate(samples, deltas),
            Field::Nerf {
                model,
                density_noise,
                ..
            } => model.evaluate(samples, directions, *density_noise),
        }
    }
}
