//! What a sampler kind is: the settings a config's `sampler` section gives
//! ([`SamplerSettings`]) and how the kind that `sampler.type` names turns them into a sampler
//! ([`SamplerKind`]). The list of kinds is [`crate::sampler_registry`].

use std::sync::Arc;

use anyhow::Result;

use crate::ray_sampler::RaySampler;

/// The `sampler` section's numbers, whatever the kind (each kind checks the ones it does not
/// take are left at their defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplerSettings {
    /// Samples per ray on `[min_depth, max_depth]`.
    pub n_pts_per_ray: usize,
    /// Depth of the first sample along each ray.
    pub min_depth: f64,
    /// Depth of the last sample of the near part.
    pub max_depth: f64,
    /// Depths per ray added from a coarse pass's weights (0: none).
    pub n_pts_per_ray_fine: usize,
    /// Samples per ray uniform in disparity beyond `max_depth` (0: none).
    pub n_pts_far: usize,
    /// The far plane, where the last disparity bin ends.
    pub far_depth: f64,
}

/// A sampler kind as a config names it (`sampler.type`).
#[derive(Debug, Clone, Copy)]
pub struct SamplerKind {
    /// The name `sampler.type` writes.
    pub name: &'static str,
    /// The sampler of these settings; an error naming the key (`sampler.…`) of a setting the
    /// kind does not take or a bad value.
    pub build: fn(&SamplerSettings) -> Result<Arc<dyn RaySampler>>,
}

impl nerf_core::registry::Named for SamplerKind {
    fn name(&self) -> &'static str {
        self.name
    }
}
