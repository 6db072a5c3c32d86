//! What a sampler kind is: the `sampler` section of a config, read straight into
//! [`SamplerSettings`], and how the kind that `sampler.type` names turns it into a sampler
//! ([`SamplerKind`]). The list of kinds is [`crate::sampler_registry`].

use std::sync::Arc;

use anyhow::Result;
use serde::Deserialize;

use crate::ray_sampler::RaySampler;
use crate::sampler::StratifiedSampler;

/// A config's `sampler` section, whatever the kind (each kind checks the keys it does not
/// take are left at their defaults).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplerSettings {
    /// `sampler.type`: a registered kind, the homework's `stratified` by default (the
    /// registry reads a kind by its name: [`crate::sampler_registry`]).
    #[serde(rename = "type", default)]
    pub kind: &'static SamplerKind,
    /// Samples per ray on `[min_depth, max_depth]` (`sampler.n_pts_per_ray`).
    pub n_pts_per_ray: usize,
    /// Depth of the first sample along each ray, in world units (`sampler.min_depth`).
    pub min_depth: f64,
    /// Depth of the last sample of the near part (`sampler.max_depth`).
    pub max_depth: f64,
    /// Coarse-to-fine sampling (`sampler.n_pts_per_ray_fine`, default 0 = off): this many
    /// more depths per ray drawn from the weights of a coarse pass over the `n_pts_per_ray`
    /// stratified ones ([`crate::hierarchical`]).
    #[serde(default)]
    pub n_pts_per_ray_fine: usize,
    /// With `type: depth_then_disparity`: samples per ray uniform in disparity beyond
    /// `max_depth` (`sampler.n_pts_far`; 0: none).
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

impl SamplerSettings {
    /// The homework's stratified sampling of `n_pts_per_ray` depths on
    /// `[min_depth, max_depth]`, every other key at its default.
    #[cfg(test)]
    fn stratified(n_pts_per_ray: usize, min_depth: f64, max_depth: f64) -> Self {
        Self {
            kind: Default::default(),
            n_pts_per_ray,
            min_depth,
            max_depth,
            n_pts_per_ray_fine: 0,
            n_pts_far: 0,
            far_depth: default_far_depth(),
        }
    }

    /// The sampler the section's kind builds from it: for `stratified`, `n_pts_per_ray`
    /// stratified depths on `[min_depth, max_depth]`, and, with `n_pts_per_ray_fine` > 0,
    /// that many more drawn from a coarse pass's weights. An error names the key of a bad
    /// value.
    pub fn sampler(&self) -> Result<Arc<dyn RaySampler>> {
        (self.kind.build)(self)
    }

    /// Samples drawn per ray before any refinement (`n_pts_per_ray`, plus `n_pts_far` for
    /// `depth_then_disparity`): the sampler's own count; `n_pts_per_ray` for settings that
    /// make no sampler.
    pub fn drawn_per_ray(&self) -> usize {
        self.sampler()
            .map_or(self.n_pts_per_ray, |s| s.drawn_per_ray())
    }

    /// The stratified depths alone (the SDF fit and the float64 reference sample only these).
    pub fn stratified_sampler(&self) -> Result<StratifiedSampler> {
        StratifiedSampler::new(self.n_pts_per_ray, self.min_depth, self.max_depth)
    }

    /// One sample step: the spacing of `n_pts_per_ray` depths over `[min_depth, max_depth]`
    /// (at least 1e-6); for `depth_then_disparity`, the step of its near, uniform part.
    pub fn step(&self) -> f64 {
        let n = self.n_pts_per_ray.max(2) - 1;
        ((self.max_depth - self.min_depth) / n as f64).max(1e-6)
    }
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

/// Kinds are one when their names are (the registry holds each name once).
impl PartialEq for SamplerKind {
    fn eq(&self, other: &Self) -> bool {
        self.name == other.name
    }
}

impl nerf_core::registry::Named for SamplerKind {
    fn name(&self) -> &'static str {
        self.name
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_section_reads_with_its_defaults_and_names_its_kind() {
        let s: SamplerSettings =
            serde_json::from_str(r#"{"n_pts_per_ray": 8, "min_depth": 0.5, "max_depth": 4.5}"#)
                .unwrap();
        assert_eq!(s, SamplerSettings::stratified(8, 0.5, 4.5));
        assert_eq!(s.kind.name, "stratified");
        assert!((s.step() - 4.0 / 7.0).abs() < 1e-15);
        let far: SamplerSettings = serde_json::from_str(
            r#"{"type": "depth_then_disparity", "n_pts_per_ray": 8, "min_depth": 0.1,
                "max_depth": 2.0, "n_pts_far": 4}"#,
        )
        .unwrap();
        assert_eq!(far.kind.name, "depth_then_disparity");
        assert_eq!(far.drawn_per_ray(), 12);
        let unknown = serde_json::from_str::<SamplerSettings>(
            r#"{"type": "pdf", "n_pts_per_ray": 8, "min_depth": 0, "max_depth": 1}"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            unknown.contains("unknown `pdf` (expected stratified or depth_then_disparity)"),
            "{unknown}"
        );
    }
}
