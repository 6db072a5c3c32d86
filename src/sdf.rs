//! Signed distance functions and the homework's SDF volume (SDF → density → σ).

use anyhow::Result;
use candle_core::{Tensor, D};

use crate::field::FieldOutput;
use crate::sampler::RaySamples;

/// An analytic signed distance function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sdf {
    /// Axis-aligned box.
    Box { center: [f32; 3], side_lengths: [f32; 3] },
    /// Sphere.
    Sphere { center: [f32; 3], radius: f32 },
}

impl Sdf {
    pub fn center(&self) -> [f32; 3] {
        match self {
            Sdf::Box { center, .. } | Sdf::Sphere { center, .. } => *center,
        }
    }

    /// Signed distance of each point (negative inside).
    ///
    /// `points`: `(N, S, 3)`; returns `(N, S, 1)`.
    pub fn signed_distance(&self, points: &Tensor) -> Result<Tensor> {
        let center = Tensor::new(&self.center(), points.device())?.to_dtype(points.dtype())?;
        let offset = points.broadcast_sub(&center)?;
        match self {
            Sdf::Box { side_lengths, .. } => {
                let half = Tensor::new(side_lengths, points.device())?.to_dtype(points.dtype())?.affine(0.5, 0.0)?;
                // q = |p − c| − s/2; sdf = ‖max(q, 0)‖ + min(max_k q_k, 0)
                let q = offset.abs()?.broadcast_sub(&half)?;
                let outside = q.relu()?.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?;
                let inside = q.max_keepdim(D::Minus1)?.minimum(0f32)?;
                Ok(outside.add(&inside)?)
            }
            Sdf::Sphere { radius, .. } => {
                Ok(offset.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?.affine(1.0, -(*radius as f64))?)
            }
        }
    }
}

/// The homework's SDF → density: `α · (½·e^(−s/β) if s > 0 else 1 − ½·e^(s/β))`.
///
/// Written with `e^(−|s|/β)` so that neither branch overflows. `sdf`: any shape; same shape out.
pub fn sdf_to_density(sdf: &Tensor, alpha: f64, beta: f64) -> Result<Tensor> {
    let e = sdf.abs()?.affine(-1.0 / beta, 0.0)?.exp()?;
    let outside = e.affine(0.5, 0.0)?;
    let inside = e.affine(-0.5, 1.0)?;
    Ok(sdf.gt(0f32)?.where_cond(&outside, &inside)?.affine(alpha, 0.0)?)
}

/// The homework's density → volume density: `σ = −ln(1 − density) / Δ`.
///
/// `density`, `deltas`: `(N, S, 1)`; returns `(N, S, 1)`. Density 1 gives σ = ∞, which the
/// renderer treats as an opaque sample (see `renderer`).
pub fn density_to_sigma(density: &Tensor, deltas: &Tensor) -> Result<Tensor> {
    Ok(density.affine(-1.0, 1.0)?.log()?.neg()?.div(deltas)?)
}

/// A volume defined by an SDF, with the homework's colour options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SdfVolume {
    pub sdf: Sdf,
    pub alpha: f64,
    pub beta: f64,
    /// Colour `clamp(|p − center|, 0.02, 0.98) · feature` instead of the constant feature.
    pub rainbow: bool,
    pub feature: [f32; 3],
}

impl SdfVolume {
    /// σ and colour at every sample.
    ///
    /// `samples`: points `(N, S, 3)`; `deltas`: `(N, S, 1)`; returns density `(N, S, 1)` and
    /// feature `(N, S, 3)`.
    pub fn evaluate(&self, samples: &RaySamples, deltas: &Tensor) -> Result<FieldOutput> {
        let points = &samples.points;
        let sdf = self.sdf.signed_distance(points)?;
        let density = density_to_sigma(&sdf_to_density(&sdf, self.alpha, self.beta)?, deltas)?;
        let device = points.device();
        let feature = Tensor::new(&self.feature, device)?.to_dtype(points.dtype())?;
        let feature = if self.rainbow {
            let center = Tensor::new(&self.sdf.center(), device)?.to_dtype(points.dtype())?;
            points
                .broadcast_sub(&center)?
                .abs()?
                .clamp(0.02f32, 0.98f32)?
                .broadcast_mul(&feature)?
        } else {
            feature.broadcast_as(points.shape())?.contiguous()?
        };
        Ok(FieldOutput { density, feature })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn pts(v: &[[f32; 3]]) -> Tensor {
        let flat: Vec<f32> = v.iter().flatten().copied().collect();
        Tensor::from_vec(flat, (1, v.len(), 3), &Device::Cpu).unwrap()
    }

    fn values(t: &Tensor) -> Vec<f32> {
        t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
    }

    #[test]
    fn box_sdf_by_hand() {
        let b = Sdf::Box { center: [0.0, 0.0, 0.0], side_lengths: [2.0, 2.0, 2.0] };
        let d = values(&b.signed_distance(&pts(&[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [2.0, 2.0, 1.0], [0.5, 0.0, 0.0]])).unwrap());
        let expected = [-1.0, 2.0, 2f32.sqrt(), -0.5];
        for (a, b) in d.iter().zip(expected) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
    }

    #[test]
    fn sphere_sdf_by_hand() {
        let s = Sdf::Sphere { center: [1.0, 0.0, 0.0], radius: 0.5 };
        let d = values(&s.signed_distance(&pts(&[[1.0, 0.0, 0.0], [1.0, 2.0, 0.0]])).unwrap());
        assert_eq!(d, vec![-0.5, 1.5]);
    }

    #[test]
    fn density_matches_the_homework_formula_in_f64() {
        let (alpha, beta) = (1.0, 0.05);
        let s = [-1.0f32, -0.1, -1e-3, 0.0, 1e-3, 0.1, 1.0, 100.0, -100.0];
        let t = Tensor::new(&s, &Device::Cpu).unwrap();
        let d = values(&sdf_to_density(&t, alpha, beta).unwrap());
        for (si, di) in s.iter().zip(d) {
            let si = *si as f64;
            let r = alpha * if si > 0.0 { 0.5 * (-si / beta).exp() } else { 1.0 - 0.5 * (si / beta).exp() };
            assert!((di as f64 - r).abs() < 1e-6, "s={si}: {di} vs {r}");
            assert!(di.is_finite());
        }
    }

    #[test]
    fn rainbow_colour_is_clamped_offset() {
        let v = SdfVolume {
            sdf: Sdf::Box { center: [0.0, 0.0, 0.0], side_lengths: [1.0, 1.0, 1.0] },
            alpha: 1.0,
            beta: 0.05,
            rainbow: true,
            feature: [1.0, 1.0, 1.0],
        };
        let points = pts(&[[0.5, -2.0, 0.0], [0.0, 0.0, 0.0]]);
        let lengths = Tensor::new(&[1f32, 2.0], &Device::Cpu).unwrap().reshape((1, 2, 1)).unwrap();
        let samples = RaySamples { points, lengths: lengths.clone() };
        let out = v.evaluate(&samples, &crate::renderer::deltas(&lengths).unwrap()).unwrap();
        assert_eq!(out.feature.dims(), &[1, 2, 3]);
        assert_eq!(out.density.dims(), &[1, 2, 1]);
        assert_eq!(values(&out.feature), vec![0.5, 0.98, 0.02, 0.02, 0.02, 0.02]);
    }
}
