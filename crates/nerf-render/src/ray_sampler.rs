//! The sampler seam: where along each ray the field is evaluated.
//!
//! Every sampling strategy implements [`RaySampler`], each in a file of its own (nerfstudio
//! keeps all of its samplers as classes of one file, `model_components/ray_samplers.py`; the
//! trait plays the part of its `Sampler` base class):
//! [`crate::sampler::StratifiedSampler`] (the homework's),
//! [`crate::hierarchical::CoarseToFineSampler`] (pytorch3d's NeRF project's
//! coarse-to-fine) and `crate::disparity_sampler::DepthThenDisparitySampler`
//! (unbounded scenes: uniform in depth near the cameras, uniform in disparity beyond). Each
//! draws depths per ray ([`RaySampler::compact_lengths`]); a strategy that places further
//! depths by looking at the field (coarse-to-fine, a proposal network) does so in
//! [`RaySampler::refine`], and its depths are then rendered densely.

use anyhow::Result;
use candle_core::Tensor;

use crate::field::Field;
use crate::sampler::StratifiedSampler;
use nerf_core::rays::Rays;
use nerf_kernels::distortion_loss::RaySpacing;

/// A sampling strategy for the renderer.
pub trait RaySampler: std::fmt::Debug + Send + Sync {
    /// Depths drawn per ray by [`RaySampler::compact_lengths`] (before any refinement).
    fn drawn_per_ray(&self) -> usize;

    /// The depths every pass starts from, without repeats: `(1, S, 1)` shared by every ray
    /// without `jitter`, `(N, S, 1)` per ray with it (training), increasing along each ray,
    /// in the rays' dtype; `S` = [`RaySampler::drawn_per_ray`].
    fn compact_lengths(
        &self,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor>;

    /// [`RaySampler::compact_lengths`] for every ray: `(N, S, 1)`.
    fn lengths(&self, rays: &Rays, jitter: Option<&mut dyn rand::RngCore>) -> Result<Tensor> {
        let lengths = self.compact_lengths(rays, jitter)?;
        let (_, s, _) = lengths.dims3()?;
        Ok(lengths.broadcast_as((rays.len(), s, 1))?.contiguous()?)
    }

    /// Depths per ray that the renderer composites.
    fn samples_per_ray(&self) -> usize {
        self.drawn_per_ray()
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

    /// The depths to render, `(N, S', 1)`, from the drawn depths `(N, S, 1)` of `rays`:
    /// the drawn ones themselves unless the strategy refines them using `field`
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

    /// The normalised ray distance the distortion loss is measured in: the spacing in which
    /// this sampler's bins are equal (`None` where it has none, as for refined depths).
    fn spacing(&self) -> Option<RaySpacing> {
        None
    }
}

/// The homework's stratified sampler: its own depths, unrefined.
impl RaySampler for StratifiedSampler {
    fn drawn_per_ray(&self) -> usize {
        self.n_pts_per_ray
    }

    fn compact_lengths(
        &self,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        StratifiedSampler::compact_lengths(self, rays, jitter)
    }

    fn spacing(&self) -> Option<RaySpacing> {
        (self.min_depth < self.max_depth).then_some(RaySpacing::Linear {
            near: self.min_depth,
            far: self.max_depth,
        })
    }
}
