//! Signed distance functions and the homework's SDF volume (SDF → density → σ).

use anyhow::Result;
use candle_core::{CpuStorage, CustomOp2, DType, Layout, Shape, Tensor, D};
use rayon::prelude::*;

use crate::kernels::storage::contiguous_f32;

use crate::render::field::FieldOutput;
use crate::render::sampler::RaySamples;

/// An analytic signed distance function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sdf {
    /// Axis-aligned box.
    Box {
        center: [f32; 3],
        side_lengths: [f32; 3],
    },
    /// Sphere.
    Sphere { center: [f32; 3], radius: f32 },
}

impl Sdf {
    /// The shape's centre in world coordinates.
    pub fn center(&self) -> [f32; 3] {
        match self {
            Sdf::Box { center, .. } | Sdf::Sphere { center, .. } => *center,
        }
    }

    /// Signed distance of one point (negative inside); the same maths as
    /// [`Sdf::signed_distance`] on a single point.
    pub fn distance(&self, p: [f32; 3]) -> f32 {
        match self {
            Sdf::Box {
                center,
                side_lengths,
            } => {
                let q: [f32; 3] =
                    std::array::from_fn(|k| (p[k] - center[k]).abs() - 0.5 * side_lengths[k]);
                let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt();
                let inside = q[0].max(q[1]).max(q[2]).min(0.0);
                outside + inside
            }
            Sdf::Sphere { center, radius } => {
                (0..3)
                    .map(|k| (p[k] - center[k]).powi(2))
                    .sum::<f32>()
                    .sqrt()
                    - radius
            }
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
                let half = Tensor::new(side_lengths, points.device())?
                    .to_dtype(points.dtype())?
                    .affine(0.5, 0.0)?;
                // q = |p − c| − s/2; sdf = ‖max(q, 0)‖ + min(max_k q_k, 0)
                let q = offset.abs()?.broadcast_sub(&half)?;
                let outside = q.relu()?.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?;
                let inside = q.max_keepdim(D::Minus1)?.minimum(0f32)?;
                Ok(outside.add(&inside)?)
            }
            Sdf::Sphere { radius, .. } => Ok(offset
                .sqr()?
                .sum_keepdim(D::Minus1)?
                .sqrt()?
                .affine(1.0, -(*radius as f64))?),
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
    Ok(sdf
        .gt(0f32)?
        .where_cond(&outside, &inside)?
        .affine(alpha, 0.0)?)
}

/// [`sdf_to_density`] for one value.
pub fn sdf_to_density_scalar(sdf: f32, alpha: f64, beta: f64) -> f32 {
    let e = (sdf.abs() * (-1.0 / beta) as f32).exp();
    let d = if sdf > 0.0 { 0.5 * e } else { 1.0 - 0.5 * e };
    d * alpha as f32
}

/// [`density_to_sigma`] for one value.
pub fn density_to_sigma_scalar(density: f32, delta: f32) -> f32 {
    -(1.0 - density).ln() / delta
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
    /// σ and colour at every sample. On the CPU with f32 data this runs as one fused,
    /// multi-threaded kernel; elsewhere as Candle tensor ops ([`SdfVolume::evaluate_tensor_ops`]).
    ///
    /// `samples`: points `(N, S, 3)`; `deltas`: `(N, S, 1)`; returns density `(N, S, 1)` and
    /// feature `(N, S, 3)`.
    pub fn evaluate(&self, samples: &RaySamples, deltas: &Tensor) -> Result<FieldOutput> {
        let points = &samples.points;
        if !(points.device().is_cpu() && points.dtype() == DType::F32) {
            return self.evaluate_tensor_ops(samples, deltas);
        }
        let fused = points
            .contiguous()?
            .apply_op2_no_bwd(&deltas.contiguous()?, &FusedSdfVolume(*self))?;
        Ok(FieldOutput {
            density: fused.narrow(2, 0, 1)?,
            feature: fused.narrow(2, 1, 3)?,
        })
    }

    /// σ and colour of one sample: `(σ, [r, g, b])`.
    pub fn evaluate_point(&self, p: [f32; 3], delta: f32) -> (f32, [f32; 3]) {
        let density = sdf_to_density_scalar(self.sdf.distance(p), self.alpha, self.beta);
        let sigma = density_to_sigma_scalar(density, delta);
        let feature = if self.rainbow {
            let c = self.sdf.center();
            std::array::from_fn(|k| (p[k] - c[k]).abs().clamp(0.02, 0.98) * self.feature[k])
        } else {
            self.feature
        };
        (sigma, feature)
    }

    /// [`SdfVolume::evaluate`] written as Candle tensor ops (any device, differentiable).
    ///
    /// `samples.points`: `(N, S, 3)`; `deltas`: `(N, S, 1)`. Returns density σ `(N, S, 1)` and
    /// colour `(N, S, 3)`.
    pub fn evaluate_tensor_ops(
        &self,
        samples: &RaySamples,
        deltas: &Tensor,
    ) -> Result<FieldOutput> {
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

/// Fused CPU kernel: points `(N, S, 3)` and deltas `(N, S, 1)` → `(N, S, 4)` = `[σ, r, g, b]`.
struct FusedSdfVolume(SdfVolume);

impl CustomOp2 for FusedSdfVolume {
    fn name(&self) -> &'static str {
        "fused-sdf-volume"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let points = contiguous_f32(s1, l1, "fused-sdf-volume")?;
        let deltas = contiguous_f32(s2, l2, "fused-sdf-volume")?;
        let dims = l1.shape().dims();
        if points.len() != 3 * deltas.len() {
            candle_core::bail!("fused-sdf-volume: points and deltas disagree in size");
        }
        let mut out = vec![0f32; 4 * deltas.len()];
        const BLOCK: usize = 4096;
        out.par_chunks_mut(4 * BLOCK)
            .zip(points.par_chunks(3 * BLOCK))
            .zip(deltas.par_chunks(BLOCK))
            .for_each(|((o, p), d)| {
                for ((o, p), &delta) in o.chunks_exact_mut(4).zip(p.chunks_exact(3)).zip(d) {
                    let (sigma, f) = self.0.evaluate_point([p[0], p[1], p[2]], delta);
                    o.copy_from_slice(&[sigma, f[0], f[1], f[2]]);
                }
            });
        Ok((CpuStorage::F32(out), Shape::from((dims[0], dims[1], 4))))
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
    fn fused_kernel_matches_tensor_ops() {
        use crate::core::camera::surround_cameras;
        use crate::core::rays::Rays;
        use crate::render::sampler::StratifiedSampler;
        let cam = surround_cameras(3.0, 20, glam::DVec3::Y, 1.0)[3];
        let rays = Rays::for_image(&cam, 13, 9, &Device::Cpu).unwrap();
        let samples = StratifiedSampler::new(17, 0.0, 5.0)
            .unwrap()
            .sample(&rays, None)
            .unwrap();
        let deltas = crate::render::renderer::deltas(&samples.lengths).unwrap();
        for (sdf, rainbow) in [
            (
                Sdf::Box {
                    center: [0.1, 0.0, -0.2],
                    side_lengths: [1.75, 1.0, 1.5],
                },
                true,
            ),
            (
                Sdf::Sphere {
                    center: [0.0, 0.3, 0.0],
                    radius: 1.0,
                },
                false,
            ),
        ] {
            let v = SdfVolume {
                sdf,
                alpha: 1.0,
                beta: 0.05,
                rainbow,
                feature: [1.0, 0.5, 0.25],
            };
            let a = v.evaluate(&samples, &deltas).unwrap();
            let b = v.evaluate_tensor_ops(&samples, &deltas).unwrap();
            assert_eq!(a.density.dims(), b.density.dims());
            assert_eq!(a.feature.dims(), b.feature.dims());
            for (x, y) in values(&a.density).iter().zip(values(&b.density)) {
                assert!(
                    x == &y || (x - y).abs() <= 1e-5 * y.abs().max(1.0),
                    "{x} vs {y}"
                );
            }
            assert_eq!(values(&a.feature), values(&b.feature));
        }
    }

    #[test]
    fn box_sdf_by_hand() {
        let b = Sdf::Box {
            center: [0.0, 0.0, 0.0],
            side_lengths: [2.0, 2.0, 2.0],
        };
        let d = values(
            &b.signed_distance(&pts(&[
                [0.0, 0.0, 0.0],
                [3.0, 0.0, 0.0],
                [2.0, 2.0, 1.0],
                [0.5, 0.0, 0.0],
            ]))
            .unwrap(),
        );
        let expected = [-1.0, 2.0, 2f32.sqrt(), -0.5];
        for (a, b) in d.iter().zip(expected) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
    }

    #[test]
    fn sphere_sdf_by_hand() {
        let s = Sdf::Sphere {
            center: [1.0, 0.0, 0.0],
            radius: 0.5,
        };
        let d = values(
            &s.signed_distance(&pts(&[[1.0, 0.0, 0.0], [1.0, 2.0, 0.0]]))
                .unwrap(),
        );
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
            let r = alpha
                * if si > 0.0 {
                    0.5 * (-si / beta).exp()
                } else {
                    1.0 - 0.5 * (si / beta).exp()
                };
            assert!((di as f64 - r).abs() < 1e-6, "s={si}: {di} vs {r}");
            assert!(di.is_finite());
        }
    }

    #[test]
    fn rainbow_colour_is_clamped_offset() {
        let v = SdfVolume {
            sdf: Sdf::Box {
                center: [0.0, 0.0, 0.0],
                side_lengths: [1.0, 1.0, 1.0],
            },
            alpha: 1.0,
            beta: 0.05,
            rainbow: true,
            feature: [1.0, 1.0, 1.0],
        };
        let points = pts(&[[0.5, -2.0, 0.0], [0.0, 0.0, 0.0]]);
        let lengths = Tensor::new(&[1f32, 2.0], &Device::Cpu)
            .unwrap()
            .reshape((1, 2, 1))
            .unwrap();
        let samples = RaySamples {
            points,
            lengths: lengths.clone(),
        };
        let out = v
            .evaluate(
                &samples,
                &crate::render::renderer::deltas(&lengths).unwrap(),
            )
            .unwrap();
        assert_eq!(out.feature.dims(), &[1, 2, 3]);
        assert_eq!(out.density.dims(), &[1, 2, 1]);
        assert_eq!(
            values(&out.feature),
            vec![0.5, 0.98, 0.02, 0.02, 0.02, 0.02]
        );
    }
}
