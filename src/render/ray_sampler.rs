//! The sampler seam: where along each ray the field is evaluated.
//!
//! Every sampling strategy implements [`RaySampler`] in a file of its own, as nerfstudio's
//! `ray_samplers.py` lists its samplers: [`crate::render::sampler::StratifiedSampler`] (the
//! homework's) and [`crate::render::hierarchical::CoarseToFineSampler`] (pytorch3d's NeRF
//! project's coarse-to-fine). Each starts from stratified depths; a strategy that places
//! further depths by looking at the field (coarse-to-fine, a proposal network) does so in
//! [`RaySampler::refine`], and its depths are then rendered densely.

use anyhow::Result;
use candle_core::Tensor;

use crate::core::rays::Rays;
use crate::render::field::Field;
use crate::render::sampler::StratifiedSampler;

/// A sampling strategy for the renderer.
pub trait RaySampler: std::fmt::Debug + Send + Sync {
    /// The stratified depths every pass starts from (count and range; jittered in training).
    fn stratified(&self) -> &StratifiedSampler;

    /// Depths per ray that the renderer composites.
    fn samples_per_ray(&self) -> usize {
        self.stratified().n_pts_per_ray
    }

    /// Field evaluations per ray (more than [`RaySampler::samples_per_ray`] when a pass probes
    /// the field first).
    fn evaluations_per_ray(&self) -> usize {
        self.samples_per_ray()
    }

    /// Whether [`RaySampler::refine`] looks at the field. Refined depths are rendered densely
    /// (no empty-space skipping); unrefined ones may be marched through an occupancy grid.
    fn refines(&self) -> bool {
        false
    }

    /// The depths to render, `(N, S', 1)`, from the stratified depths `(N, S, 1)` of `rays`:
    /// the stratified ones themselves unless the strategy refines them using `field`
    /// (detached: no gradient flows into the choice of depths). `jitter`: the training
    /// randomness, `None` when rendering.
    fn refine(
        &self,
        _field: &dyn Field,
        _rays: &Rays,
        stratified: Tensor,
        _jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        Ok(stratified)
    }
}

/// The homework's stratified sampler: its own depths, unrefined.
impl RaySampler for StratifiedSampler {
    fn stratified(&self) -> &StratifiedSampler {
        self
    }
}

/// A shared sampler is a sampler (configs hand theirs out as `Arc<dyn RaySampler>`).
impl<S: RaySampler + ?Sized> RaySampler for std::sync::Arc<S> {
    fn stratified(&self) -> &StratifiedSampler {
        (**self).stratified()
    }

    fn samples_per_ray(&self) -> usize {
        (**self).samples_per_ray()
    }

    fn evaluations_per_ray(&self) -> usize {
        (**self).evaluations_per_ray()
    }

    fn refines(&self) -> bool {
        (**self).refines()
    }

    fn refine(
        &self,
        field: &dyn Field,
        rays: &Rays,
        stratified: Tensor,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        (**self).refine(field, rays, stratified, jitter)
    }
}
