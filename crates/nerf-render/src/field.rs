//! The field abstraction: what the renderer queries at sample points. The renderer, the
//! occupancy grid and the skipping pass see a field only through [`Field`], so a new field
//! kind is one new file implementing it; the crate's own fields add their fused kernels
//! through [`FieldFastPaths`], an inside seam a new kind need not know.

use anyhow::Result;
use candle_core::Tensor;

use crate::occupancy::OccupancyGrid;
use crate::sampler::RaySamples;
use nerf_core::rays::Rays;

/// Volume density and feature (colour) at every sample.
#[derive(Debug, Clone)]
pub struct FieldOutput {
    /// `(N, S, 1)` volume density σ ≥ 0 (may be +∞ for an opaque sample).
    pub density: Tensor,
    /// `(N, S, 3)` colour.
    pub feature: Tensor,
}

impl FieldOutput {
    /// A packed evaluation run on dense samples. `points` `(N, S, 3)` are flattened to
    /// `(N·S, 3)`, sample `i` of that order on ray `i / S`; `evaluate` gets them with each
    /// sample's ray, as a `(N·S,)` u32 tensor on the points' device and as the same values on
    /// the host, and returns density `(N·S, 1)` and feature `(N·S, 3)`, reshaped here to
    /// `(N, S, 1)` and `(N, S, 3)`.
    pub fn from_packed(
        points: &Tensor,
        evaluate: impl FnOnce(&Tensor, (&Tensor, &[u32])) -> Result<(Tensor, Tensor)>,
    ) -> Result<Self> {
        let (n, s, _) = points.dims3()?;
        let rays: Vec<u32> = (0..n * s).map(|i| (i / s) as u32).collect();
        let ray_index = Tensor::new(rays.as_slice(), points.device())?;
        let flat = points.reshape((n * s, 3))?;
        let (density, feature) = evaluate(&flat, (&ray_index, &rays))?;
        Ok(Self {
            density: density.reshape((n, s, 1))?,
            feature: feature.reshape((n, s, 3))?,
        })
    }
}

pub use nerf_kernels::composite::Composited;

/// The samples a field without its own [`FieldFastPaths::max_samples_per_chunk`] is given at
/// once: a size that suits a field keeping large activations a sample.
pub(crate) const DEFAULT_SAMPLES_PER_CHUNK: usize = 1 << 16;

/// A radiance field: what a new field kind implements. Only [`Field::evaluate`] is required;
/// a field with fused kernels also offers them through [`Field::fast_paths`].
pub trait Field {
    /// Evaluates the field at the samples of N rays.
    ///
    /// `samples`: points `(N, S, 3)`, lengths `(N, S, 1)`; `deltas`: `(N, S, 1)` spacings;
    /// `directions`: `(N, 3)` unit ray directions. Returns density `(N, S, 1)` and feature
    /// `(N, S, 3)`.
    fn evaluate(
        &self,
        samples: &RaySamples,
        deltas: &Tensor,
        directions: &Tensor,
    ) -> Result<FieldOutput>;

    /// The same field for rays of the training cameras `camera_index` `(N,)` u32 (one per
    /// ray of the batch it will see), for a field with parts learnt per training image
    /// (appearance); `None` (the default) when it has none, and the field is used as it is.
    fn for_cameras(&self, _camera_index: &Tensor) -> Result<Option<Box<dyn Field + '_>>> {
        Ok(None)
    }

    /// Where the field can have density, when it is rendered through an occupancy grid
    /// ([`crate::occupied_field::OccupiedField`]; samples elsewhere are skipped when the field
    /// has packed evaluation, [`FieldFastPaths::evaluate_packed`]). A field kind leaves it.
    fn occupancy(&self) -> Option<&OccupancyGrid> {
        None
    }

    /// Density alone at `points` `(M, 3)`: `(M, 1)` (meshes, grids), for fields with packed
    /// evaluation, whose density does not depend on the direction. The default evaluates
    /// [`FieldFastPaths::evaluate_packed`] with every point on one ray along +z and keeps the
    /// density; an error for a field without packed evaluation.
    fn density(&self, points: &Tensor) -> Result<Tensor> {
        let m = points.dim(0)?;
        let dev = points.device();
        let directions = Tensor::new(&[[0f32, 0.0, 1.0]], dev)?.to_dtype(points.dtype())?;
        let ray_index = Tensor::zeros(m, candle_core::DType::U32, dev)?;
        Ok(packed_evaluation(self, points, &ray_index, &directions)?.0)
    }

    /// The field's fast paths, when it has kernels for them; `None` (the default) renders
    /// through [`Field::evaluate`] alone, in chunks of `DEFAULT_SAMPLES_PER_CHUNK` samples.
    fn fast_paths(&self) -> Option<&dyn FieldFastPaths> {
        None
    }
}

/// The renderer's fast paths into a field: how the crate's own fields (the SDF volume, the
/// NeRF MLP, the hash grid) hand it fused kernels and packed evaluation. An inside seam
/// between the renderer and the kernels, not part of what a new field kind implements; a field
/// offers it through [`Field::fast_paths`], and every method has the default of a field
/// without the kernel.
pub trait FieldFastPaths {
    /// Colour `(N, 3)`, depth `(N, 1)` and opacity `(N, 1)` of `rays` (N) densely sampled at
    /// `lengths` `(N, S, 1)`, rendered by the field itself in one fused pass: the values that
    /// [`Field::evaluate`] followed by the renderer's compositing give, and differentiable
    /// the same way. `None` (the default) when the field has no such kernel for these inputs;
    /// the renderer then samples, evaluates and composites.
    fn render_fused(&self, _rays: &Rays, _lengths: &Tensor) -> Result<Option<Composited>> {
        Ok(None)
    }

    /// The most samples (rays × points per ray) to evaluate at once. The renderer lowers its
    /// `chunk_size` to fit, which bounds memory without changing any output. The default is
    /// `DEFAULT_SAMPLES_PER_CHUNK`; the fields that keep little a sample return more.
    fn max_samples_per_chunk(&self) -> usize {
        DEFAULT_SAMPLES_PER_CHUNK
    }

    /// Whether [`FieldFastPaths::evaluate_packed`] is implemented. Fields whose σ does not
    /// depend on the spacing implement it; the others (the default) are evaluated densely.
    fn supports_packed(&self) -> bool {
        false
    }

    /// Evaluates M samples drawn from N rays, for the skipping pass (`render::skipping`).
    ///
    /// `points`: `(M, 3)`; `ray_index`: `(M,)` u32, each sample's ray; `directions`: `(N, 3)`.
    /// Returns density `(M, 1)` and feature `(M, 3)`, the values [`Field::evaluate`] gives at
    /// those samples.
    fn evaluate_packed(
        &self,
        _points: &Tensor,
        _ray_index: &Tensor,
        _directions: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        anyhow::bail!("this field is evaluated densely only (no packed evaluation)")
    }
}

/// The samples `field` evaluates at once ([`FieldFastPaths::max_samples_per_chunk`], else
/// [`DEFAULT_SAMPLES_PER_CHUNK`]).
pub(crate) fn samples_per_chunk<F: Field + ?Sized>(field: &F) -> usize {
    field
        .fast_paths()
        .map_or(DEFAULT_SAMPLES_PER_CHUNK, |f| f.max_samples_per_chunk())
}

/// Whether `field` has packed evaluation ([`FieldFastPaths::supports_packed`]).
pub fn supports_packed<F: Field + ?Sized>(field: &F) -> bool {
    field.fast_paths().is_some_and(|f| f.supports_packed())
}

/// `field`'s packed evaluation of M samples ([`FieldFastPaths::evaluate_packed`]): density
/// `(M, 1)` and feature `(M, 3)`; an error for a field without it.
pub fn packed_evaluation<F: Field + ?Sized>(
    field: &F,
    points: &Tensor,
    ray_index: &Tensor,
    directions: &Tensor,
) -> Result<(Tensor, Tensor)> {
    match field.fast_paths() {
        Some(fast) => fast.evaluate_packed(points, ray_index, directions),
        None => anyhow::bail!("this field is evaluated densely only (no packed evaluation)"),
    }
}

/// `field`'s own fused render of `rays` (N) densely sampled at `lengths` `(N, S, 1)`
/// ([`FieldFastPaths::render_fused`]): colour `(N, 3)`, depth and opacity `(N, 1)`; `None` when
/// it has none for these inputs.
pub(crate) fn render_fused<F: Field + ?Sized>(
    field: &F,
    rays: &Rays,
    lengths: &Tensor,
) -> Result<Option<Composited>> {
    match field.fast_paths() {
        Some(fast) => fast.render_fused(rays, lengths),
        None => Ok(None),
    }
}
