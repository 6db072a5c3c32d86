//! The SDF volume's maths at one point, as plain numbers: the homework's SDF → density → σ,
//! the colour, and their derivatives with respect to the point and the packed parameters
//! ([`PackedLayout`]). The fused SDF kernels (`sdf_volume`, `sdf_volume_grad`, `sdf_ray`)
//! run them per sample; their tensor-op twins are in `sdf_volume`.
//!
//! They live beside the kernels that call them, not with [`SdfVolume`] in `nerf_core::sdf`:
//! no other stage needs a volume's derivatives, so nothing here is public.

use nerf_core::sdf::{Sdf, SdfVolume};

use crate::fastexp::exp_fast;

/// Box signed distance of `p` and its derivatives: `(s, ∂s/∂center, ∂s/∂side_lengths)`.
/// `∂s/∂p = −∂s/∂center`. At the measure-zero kinks (`p_k = c_k`, ties of the largest
/// `q_k`) the choice is the one Candle's tensor ops make: `sign(0) = +1`, every tied maximum.
#[inline(always)]
pub(crate) fn box_distance_with_gradient(
    center: &[f32; 3],
    side_lengths: &[f32; 3],
    p: [f32; 3],
) -> (f32, [f32; 3], [f32; 3]) {
    let offset: [f32; 3] = std::array::from_fn(|k| p[k] - center[k]);
    let q: [f32; 3] = std::array::from_fn(|k| offset[k].abs() - 0.5 * side_lengths[k]);
    let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt();
    let max_q = q[0].max(q[1]).max(q[2]);
    let inside = max_q.min(0.0);
    // ∂s/∂q_k: the norm's part where q_k > 0, plus the inside part at the largest q_k.
    let ds_dq: [f32; 3] = std::array::from_fn(|k| {
        let norm_part = if q[k] > 0.0 && outside > 0.0 {
            q[k] / outside
        } else {
            0.0
        };
        let inside_part = if q[k] == max_q && max_q < 0.0 {
            1.0
        } else {
            0.0
        };
        norm_part + inside_part
    });
    let d_center = std::array::from_fn(|k| {
        let sign = if offset[k] >= 0.0 { 1.0 } else { -1.0 };
        -ds_dq[k] * sign
    });
    let d_sides = std::array::from_fn(|k| -0.5 * ds_dq[k]);
    (outside + inside, d_center, d_sides)
}

/// Sphere signed distance of `p` and its derivatives: `(s, ∂s/∂center, [∂s/∂radius, 0, 0])`;
/// at the centre itself `∂s/∂center` is taken as 0.
#[inline(always)]
pub(crate) fn sphere_distance_with_gradient(
    center: &[f32; 3],
    radius: f32,
    p: [f32; 3],
) -> (f32, [f32; 3], [f32; 3]) {
    let offset: [f32; 3] = std::array::from_fn(|k| p[k] - center[k]);
    let norm = offset.iter().map(|v| v.powi(2)).sum::<f32>().sqrt();
    let inv = if norm > 0.0 { 1.0 / norm } else { 0.0 };
    (norm - radius, offset.map(|v| -v * inv), [-1.0, 0.0, 0.0])
}

/// Signed distance of one point and its derivatives with respect to the shape's
/// parameters: `(s, ∂s/∂center, ∂s/∂shape)`, where the shape's parameters are the box's
/// three side lengths or the sphere's radius (the first entry; the others are 0).
/// The derivative with respect to the point is `−∂s/∂center`.
#[inline(always)]
pub(crate) fn distance_with_gradient(sdf: &Sdf, p: [f32; 3]) -> (f32, [f32; 3], [f32; 3]) {
    match sdf {
        Sdf::Box {
            center,
            side_lengths,
        } => box_distance_with_gradient(center, side_lengths, p),
        Sdf::Sphere { center, radius } => sphere_distance_with_gradient(center, *radius, p),
    }
}

#[inline]
/// Number of shape parameters: 3 side lengths for a box, 1 radius for a sphere.
pub(crate) fn shape_len(sdf: &Sdf) -> usize {
    match sdf {
        Sdf::Box { .. } => 3,
        Sdf::Sphere { .. } => 1,
    }
}

#[inline]
/// The homework's SDF → density for one value: `α · (½·e^(−s/β) if s > 0 else 1 − ½·e^(s/β))`,
/// written with `e^(−|s|/β)` so that neither branch overflows.
pub(crate) fn sdf_to_density_scalar(sdf: f32, alpha: f64, beta: f64) -> f32 {
    let e = (sdf.abs() * (-1.0 / beta) as f32).exp();
    let d = if sdf > 0.0 { 0.5 * e } else { 1.0 - 0.5 * e };
    d * alpha as f32
}

#[inline]
/// The homework's density → volume density for one value: `σ = −ln(1 − density) / Δ`.
pub(crate) fn density_to_sigma_scalar(density: f32, delta: f32) -> f32 {
    -(1.0 - density).ln() / delta
}

/// An entry of a gradient sum: `f32` for a ray's few samples, `f64` for long sums.
pub(crate) trait Accumulate {
    /// Adds `v`.
    fn accumulate(&mut self, v: f32);
}

impl Accumulate for f32 {
    fn accumulate(&mut self, v: f32) {
        *self += v;
    }
}

impl Accumulate for f64 {
    fn accumulate(&mut self, v: f32) {
        *self += v as f64;
    }
}

/// Partial derivatives `∂x/∂θ` of one sample's σ (or optical depth) with respect to the
/// volume's shape and density parameters (the colour does not enter them).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Partials {
    /// `∂x/∂center` (and `∂x/∂p = −∂x/∂center`).
    pub center: [f32; 3],
    /// `∂x/∂side_lengths` of a box, or `∂x/∂radius` of a sphere in the first entry.
    pub shape: [f32; 3],
    /// `∂x/∂α`.
    pub alpha: f32,
    /// `∂x/∂β`.
    pub beta: f32,
}

impl Partials {
    /// Adds `g · ∂x/∂θ` to `params`, laid out as `layout`.
    #[inline(always)]
    pub(crate) fn add_to<A: Accumulate>(&self, g: f32, layout: PackedLayout, params: &mut [A]) {
        for (p, c) in params.iter_mut().zip(self.center) {
            p.accumulate(g * c);
        }
        for k in 0..layout.shape_len {
            params[PackedLayout::SHAPE + k].accumulate(g * self.shape[k]);
        }
        params[layout.alpha()].accumulate(g * self.alpha);
        params[layout.beta()].accumulate(g * self.beta);
    }
}

/// Where each parameter of an [`SdfVolume`] sits in its packed form, the `(P,)` vector
/// `[center (3), side_lengths (3) or radius (1), alpha, beta, feature (3)]` (P = 11 for a box,
/// 9 for a sphere) that the differentiable fused kernels read and return gradients for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PackedLayout {
    /// Number of shape parameters (3 for a box, 1 for a sphere).
    pub shape_len: usize,
}

impl PackedLayout {
    /// Index of the first shape parameter.
    pub(crate) const SHAPE: usize = 3;

    #[inline]
    /// Index of α.
    pub(crate) fn alpha(&self) -> usize {
        Self::SHAPE + self.shape_len
    }

    #[inline]
    /// Index of β.
    pub(crate) fn beta(&self) -> usize {
        self.alpha() + 1
    }

    #[inline]
    /// Index of the first feature channel.
    pub(crate) fn feature(&self) -> usize {
        self.beta() + 1
    }

    #[inline]
    /// Length P of the packed vector.
    pub(crate) fn len(&self) -> usize {
        self.feature() + 3
    }
}

#[inline]
/// The layout of this volume's packed parameters.
pub(crate) fn packed_layout(volume: &SdfVolume) -> PackedLayout {
    PackedLayout {
        shape_len: shape_len(&volume.sdf),
    }
}

#[inline]
/// σ of one sample ([`evaluate_point`]'s, bit for bit) and its partial
/// derivatives `∂σ/∂θ`. They are 0 where `1 − density` is 0 (σ = ∞, an opaque sample
/// whose optical depth the renderer clamps) or Δ is 0.
pub(crate) fn sigma_with_partials(volume: &SdfVolume, p: [f32; 3], delta: f32) -> (f32, Partials) {
    let (s, ds_dc, ds_dshape) = distance_with_gradient(&volume.sdf, p);
    let density = sdf_to_density_scalar(s, volume.alpha, volume.beta);
    let sigma = density_to_sigma_scalar(density, delta);
    let clear = 1.0 - density;
    if delta == 0.0 || clear <= 0.0 {
        return (sigma, Partials::default());
    }
    let e = (s.abs() * (-1.0 / volume.beta) as f32).exp();
    let unit = if s > 0.0 { 0.5 * e } else { 1.0 - 0.5 * e };
    // ∂σ/∂density = 1/((1 − density)Δ); ∂density/∂s = −α e/(2β).
    let g_density = 1.0 / (clear * delta);
    let partials = density_partials(volume, g_density, (s, ds_dc, ds_dshape), e, unit);
    (sigma, partials)
}

/// `g · ∂density/∂θ` of one sample, from its signed distance and derivatives
/// `(s, ∂s/∂center, ∂s/∂shape)`, `e = e^{−|s|/β}` and the unit density `unit`
/// ([`transparency_parts`]): `∂density/∂s = −α e/(2β)`, `∂density/∂α = unit`,
/// `∂density/∂β = α e s/(2β²)`.
#[inline(always)]
fn density_partials(
    volume: &SdfVolume,
    g: f32,
    (s, ds_dc, ds_dshape): (f32, [f32; 3], [f32; 3]),
    e: f32,
    unit: f32,
) -> Partials {
    let (alpha, beta) = (volume.alpha as f32, volume.beta as f32);
    let g_s = -g * alpha * e / (2.0 * beta);
    Partials {
        center: ds_dc.map(|v| g_s * v),
        shape: ds_dshape.map(|v| g_s * v),
        alpha: g * unit,
        beta: g * alpha * e * s / (2.0 * beta * beta),
    }
}

/// Adds `g · ∂σ/∂θ` for one sample to `params` (the packed layout of
/// [`packed_layout`]; the feature entries are untouched) and returns
/// `g · ∂σ/∂p` (`= −g · ∂σ/∂center`), for [`evaluate_point`]'s σ.
pub(crate) fn sigma_vjp<A: Accumulate>(
    volume: &SdfVolume,
    p: [f32; 3],
    delta: f32,
    g: f32,
    params: &mut [A],
) -> [f32; 3] {
    if g == 0.0 {
        return [0.0; 3];
    }
    let (_, d) = sigma_with_partials(volume, p, delta);
    d.add_to(g, packed_layout(volume), params);
    d.center.map(|v| -g * v)
}

/// Adds `g · ∂colour/∂θ` for one sample to `params` (packed layout; only the centre and
/// feature entries) and returns `g · ∂colour/∂p`, for the colour of
/// [`evaluate_point`]. `g`: the gradient of the sample's `[r, g, b]`.
#[inline(always)]
pub(crate) fn colour_vjp<A: Accumulate>(
    volume: &SdfVolume,
    p: [f32; 3],
    g: [f32; 3],
    params: &mut [A],
) -> [f32; 3] {
    let f0 = packed_layout(volume).feature();
    let (scale, d_scale) = colour_factors(volume, p);
    let mut d_point = [0f32; 3];
    for k in 0..3 {
        params[f0 + k].accumulate(g[k] * scale[k]);
        // ∂colour_k/∂c_k = d_scale_k · feature_k, and ∂colour_k/∂p_k is its opposite.
        let d_center = g[k] * d_scale[k] * volume.feature[k];
        params[k].accumulate(d_center);
        d_point[k] = -d_center;
    }
    d_point
}

/// The colour of one sample as `scale_k · feature_k` per channel, and `∂scale_k/∂c_k`:
/// with `rainbow`, `scale_k = clamp(|p_k − c_k|, 0.02, 0.98)` and its derivative
/// `−sign(p_k − c_k)` inside the clamp's range (`sign(0) = +1`), 0 outside; without,
/// `scale = 1` and no derivative.
#[inline(always)]
pub(crate) fn colour_factors(volume: &SdfVolume, p: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    if !volume.rainbow {
        return ([1.0; 3], [0.0; 3]);
    }
    let c = volume.sdf.center();
    let mut scale = [0f32; 3];
    let mut d_scale = [0f32; 3];
    for k in 0..3 {
        let offset = p[k] - c[k];
        let a = offset.abs();
        scale[k] = a.clamp(0.02, 0.98);
        let inside = a > 0.02 && a < 0.98;
        let sign = if offset >= 0.0 { 1.0 } else { -1.0 };
        d_scale[k] = if inside { -sign } else { 0.0 };
    }
    (scale, d_scale)
}

/// One sample's transparency `1 − density` (≥ 0) from its signed distance `s`, with
/// `e = e^{−|s|/β}` and the unit density `½e` (outside) or `1 − ½e` (inside):
/// `(1 − α·unit, e, unit)`, `e^x` by `exp_fast`.
#[inline(always)]
pub(crate) fn transparency_parts(volume: &SdfVolume, s: f32) -> (f32, f32, f32) {
    let e = exp_fast(s.abs() * (-1.0 / volume.beta) as f32);
    let unit = if s > 0.0 { 0.5 * e } else { 1.0 - 0.5 * e };
    ((1.0 - unit * volume.alpha as f32).max(0.0), e, unit)
}

/// One sample's transparency `1 − density` (= `e^{−σΔ}` for the homework's
/// `σ = −ln(1 − density)/Δ`, whatever Δ > 0 is) and the partial derivatives of its
/// optical depth `τ = σΔ = −ln(1 − density)` with respect to the parameters, `∂τ/∂θ =
/// (∂density/∂θ)/(1 − density)`: what the backward pass of a fused render needs, with no
/// logarithm. The partials are 0 where `1 − density` is 0 (the renderer clamps τ there).
///
/// It takes the sample's signed distance and its derivatives `(s, ∂s/∂center,
/// ∂s/∂shape)` ([`box_distance_with_gradient`], [`sphere_distance_with_gradient`]), so
/// that a loop over samples can pick the shape once.
#[inline(always)]
pub(crate) fn transparency_from_distance(
    volume: &SdfVolume,
    (s, ds_dc, ds_dshape): (f32, [f32; 3], [f32; 3]),
) -> (f32, Partials) {
    let (clear, e, unit) = transparency_parts(volume, s);
    // Where the sample is opaque (clear = 0) τ is clamped: no gradient.
    let inv = if clear > 0.0 { 1.0 / clear } else { 0.0 };
    (
        clear,
        density_partials(volume, inv, (s, ds_dc, ds_dshape), e, unit),
    )
}

#[inline]
/// σ and colour of one sample: `(σ, [r, g, b])`.
pub(crate) fn evaluate_point(volume: &SdfVolume, p: [f32; 3], delta: f32) -> (f32, [f32; 3]) {
    let density = sdf_to_density_scalar(volume.sdf.distance(p), volume.alpha, volume.beta);
    let sigma = density_to_sigma_scalar(density, delta);
    (sigma, colour_at(volume, p))
}

/// Colour of one sample: the feature, or with `rainbow` `clamp(|p − center|, 0.02, 0.98) ·
/// feature`.
#[inline(always)]
pub(crate) fn colour_at(volume: &SdfVolume, p: [f32; 3]) -> [f32; 3] {
    if volume.rainbow {
        let c = volume.sdf.center();
        std::array::from_fn(|k| (p[k] - c[k]).abs().clamp(0.02, 0.98) * volume.feature[k])
    } else {
        volume.feature
    }
}
