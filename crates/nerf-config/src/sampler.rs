//! The `sampler` section and the sampler it describes (stratified, coarse-to-fine, or depth
//! then disparity for unbounded scenes).

use std::sync::Arc;

use anyhow::Result;
use serde::{Deserialize, Deserializer};

use super::Config;
use nerf_render::ray_sampler::RaySampler;
use nerf_render::sampler::StratifiedSampler;
use nerf_render::sampler_kind::{SamplerKind, SamplerSettings};
use nerf_render::sampler_registry::{find_sampler_kind, sampler_kind_names, SAMPLER_KINDS};

/// `sampler.type`: a registered sampler kind ([`nerf_render::sampler_registry`]), the
/// homework's `stratified` by default.
#[derive(Debug, Clone, Copy)]
pub struct SamplerType(pub &'static SamplerKind);

impl Default for SamplerType {
    fn default() -> Self {
        Self(&SAMPLER_KINDS[0])
    }
}

impl PartialEq for SamplerType {
    fn eq(&self, other: &Self) -> bool {
        self.0.name == other.0.name
    }
}

impl<'de> Deserialize<'de> for SamplerType {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        find_sampler_kind(&name).map(Self).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "unknown `{name}` (expected {})",
                sampler_kind_names()
            ))
        })
    }
}

/// The `sampler` section.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SamplerConfig {
    /// `sampler.type`: `stratified` (the default) or another registered kind.
    #[serde(rename = "type", default)]
    pub kind: SamplerType,
    /// Samples per ray (`sampler.n_pts_per_ray`, 1 to `super::limits::PTS_PER_RAY`).
    pub n_pts_per_ray: usize,
    /// Depth of the first sample along each ray, in world units (`sampler.min_depth`, ≥ 0).
    pub min_depth: f64,
    /// Depth of the last sample along each ray (`sampler.max_depth`, ≥ `min_depth`).
    pub max_depth: f64,
    /// Coarse-to-fine sampling (`sampler.n_pts_per_ray_fine`, default 0 = off): this many
    /// more depths per ray drawn from the weights of a coarse pass over the `n_pts_per_ray`
    /// stratified ones ([`nerf_render::hierarchical`]); not with an occupancy grid or early
    /// termination.
    #[serde(default)]
    pub n_pts_per_ray_fine: usize,
    /// With `type: depth_then_disparity`: samples per ray uniform in disparity beyond
    /// `max_depth` (`sampler.n_pts_far`, at least 1 there; 0 otherwise).
    #[serde(default)]
    pub n_pts_far: usize,
    /// With `type: depth_then_disparity`: the far plane, where the last disparity bin ends
    /// (`sampler.far_depth`, default 1000).
    #[serde(default = "default_far_depth")]
    pub far_depth: f64,
}

fn default_far_depth() -> f64 {
    1000.0
}

impl SamplerConfig {
    /// The sampler the section's kind builds from its settings: for `stratified`,
    /// `n_pts_per_ray` stratified depths on `[min_depth, max_depth]`, and, with
    /// `n_pts_per_ray_fine` > 0, that many more drawn from a coarse pass's weights.
    pub(crate) fn sampler(&self) -> Result<Arc<dyn RaySampler>> {
        (self.kind.0.build)(&SamplerSettings {
            n_pts_per_ray: self.n_pts_per_ray,
            min_depth: self.min_depth,
            max_depth: self.max_depth,
            n_pts_per_ray_fine: self.n_pts_per_ray_fine,
            n_pts_far: self.n_pts_far,
            far_depth: self.far_depth,
        })
    }

    /// Samples drawn per ray before any refinement (`n_pts_per_ray`, plus `n_pts_far` for
    /// `depth_then_disparity`): the sampler's own count; `n_pts_per_ray` for a section that
    /// makes no sampler (validation refuses it).
    pub(crate) fn drawn_per_ray(&self) -> usize {
        self.sampler()
            .map_or(self.n_pts_per_ray, |s| s.drawn_per_ray())
    }

    /// The stratified depths alone (the SDF fit and the float64 reference sample only these).
    pub(crate) fn stratified(&self) -> Result<StratifiedSampler> {
        StratifiedSampler::new(self.n_pts_per_ray, self.min_depth, self.max_depth)
    }

    /// One sample step: the spacing of `n_pts_per_ray` depths over `[min_depth, max_depth]`
    /// (at least 1e-6); for `depth_then_disparity`, the step of its near, uniform part.
    pub(crate) fn step(&self) -> f64 {
        let n = self.n_pts_per_ray.max(2) - 1;
        ((self.max_depth - self.min_depth) / n as f64).max(1e-6)
    }
}

impl Config {
    /// The `sampler` section as a sampler (`SamplerConfig::sampler`).
    pub fn sampler(&self) -> Result<Arc<dyn RaySampler>> {
        self.sampler.sampler()
    }

    /// The `sampler` section's stratified depths alone (`SamplerConfig::stratified`).
    pub fn stratified_sampler(&self) -> Result<StratifiedSampler> {
        self.sampler.stratified()
    }
}
