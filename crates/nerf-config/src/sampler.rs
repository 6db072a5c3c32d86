//! The `sampler` section, read straight into the renderer's
//! [`SamplerSettings`] (stratified, coarse-to-fine, or depth then disparity for unbounded
//! scenes).

use std::sync::Arc;

use anyhow::Result;

use super::Config;
use nerf_render::ray_sampler::RaySampler;
use nerf_render::sampler::StratifiedSampler;

impl Config {
    /// The `sampler` section as a sampler ([`nerf_render::sampler_kind::SamplerSettings::sampler`]).
    pub fn sampler(&self) -> Result<Arc<dyn RaySampler>> {
        self.sampler.sampler()
    }

    /// The `sampler` section's stratified depths alone.
    pub fn stratified_sampler(&self) -> Result<StratifiedSampler> {
        self.sampler.stratified_sampler()
    }
}
