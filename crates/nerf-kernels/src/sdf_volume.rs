//! The homework's SDF volume at sample points (SDF → density → σ, and the colour): a fused CPU
//! kernel and its tensor-op twin.
//!
//! The fused kernel reads the volume's parameters as plain numbers and has no backward pass,
//! so it runs only when nothing it reads is tracked by autograd; a volume with a trainable
//! parameter (the homework's `opt: True`) runs the twin, whose gradients reach every parameter.

use anyhow::Result;
use candle_core::{Shape, Tensor, D};
use rayon::prelude::*;

use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelOutput};
use crate::{needs_grad, use_fused};
use nerf_core::sdf::{Sdf, SdfVolume};

use crate::sdf_point::evaluate_point;

/// The shape of an SDF volume as tensors (any of them may be a trainable variable).
#[derive(Debug, Clone)]
pub enum ShapeTensors {
    /// Axis-aligned box: `center` `(3,)`, `side_lengths` `(3,)`.
    Box {
        /// Centre `(3,)` in world units.
        center: Tensor,
        /// Full side lengths `(3,)` along x, y and z.
        side_lengths: Tensor,
    },
    /// Sphere: `center` `(3,)`, `radius` `(1,)`.
    Sphere {
        /// Centre `(3,)` in world units.
        center: Tensor,
        /// Radius `(1,)` in world units.
        radius: Tensor,
    },
}

/// An SDF volume's parameters as tensors: `alpha`, `beta` `(1,)`, `feature` `(3,)`.
#[derive(Debug, Clone)]
pub struct SdfTensors {
    /// The shape's parameters.
    pub shape: ShapeTensors,
    /// Density scale α `(1,)` of the SDF → density map, in [0, 1].
    pub alpha: Tensor,
    /// Falloff β `(1,)` of the SDF → density map, in world units (> 0).
    pub beta: Tensor,
    /// Colour `clamp(|p − center|, 0.02, 0.98) · feature` instead of the constant feature.
    pub rainbow: bool,
    /// RGB colour `(3,)` (the scale of the rainbow colouring with `rainbow`).
    pub feature: Tensor,
}

impl SdfTensors {
    #[cfg(test)]
    /// `volume`'s parameters as tensors, each made by `make(name, values)`: `center` (3), then
    /// `side_lengths` (3) or `radius` (1), then `alpha`, `beta` (1) and `feature` (3), in that
    /// order (plain tensors, or variables for the ones being trained).
    pub(crate) fn from_volume<E>(
        volume: &SdfVolume,
        mut make: impl FnMut(&str, &[f32]) -> std::result::Result<Tensor, E>,
    ) -> std::result::Result<Self, E> {
        let shape = match volume.sdf {
            Sdf::Box {
                center,
                side_lengths,
            } => ShapeTensors::Box {
                center: make("center", &center)?,
                side_lengths: make("side_lengths", &side_lengths)?,
            },
            Sdf::Sphere { center, radius } => ShapeTensors::Sphere {
                center: make("center", &center)?,
                radius: make("radius", &[radius])?,
            },
        };
        Ok(SdfTensors {
            shape,
            alpha: make("alpha", &[volume.alpha as f32])?,
            beta: make("beta", &[volume.beta as f32])?,
            rainbow: volume.rainbow,
            feature: make("feature", &volume.feature)?,
        })
    }

    /// The same parameters detached from the autograd graph (constants of their current
    /// values, which the fused kernels accept).
    pub fn detach(&self) -> Self {
        let shape = match &self.shape {
            ShapeTensors::Box {
                center,
                side_lengths,
            } => ShapeTensors::Box {
                center: center.detach(),
                side_lengths: side_lengths.detach(),
            },
            ShapeTensors::Sphere { center, radius } => ShapeTensors::Sphere {
                center: center.detach(),
                radius: radius.detach(),
            },
        };
        Self {
            shape,
            alpha: self.alpha.detach(),
            beta: self.beta.detach(),
            rainbow: self.rainbow,
            feature: self.feature.detach(),
        }
    }

    /// Every parameter tensor, in a fixed order: `center` `(3,)`, then `side_lengths` `(3,)` or
    /// `radius` `(1,)`, then `alpha`, `beta` `(1,)` and `feature` `(3,)`.
    pub(crate) fn tensors(&self) -> Vec<&Tensor> {
        let mut v = match &self.shape {
            ShapeTensors::Box {
                center,
                side_lengths,
            } => vec![center, side_lengths],
            ShapeTensors::Sphere { center, radius } => vec![center, radius],
        };
        v.extend([&self.alpha, &self.beta, &self.feature]);
        v
    }

    /// The parameters packed into one `(P,)` tensor, `[center, side_lengths | radius, alpha,
    /// beta, feature]` (`sdf_point::PackedLayout`), by a differentiable
    /// concatenation: gradients with respect to it reach each variable.
    pub(crate) fn packed(&self) -> Result<Tensor> {
        let dtype = self.center().dtype();
        let parts = self
            .tensors()
            .into_iter()
            .map(|t| t.to_dtype(dtype))
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Tensor::cat(&parts, 0)?)
    }

    /// The shape's centre `(3,)`.
    pub(crate) fn center(&self) -> &Tensor {
        match &self.shape {
            ShapeTensors::Box { center, .. } | ShapeTensors::Sphere { center, .. } => center,
        }
    }

    /// The current values as plain numbers.
    pub fn values(&self) -> Result<SdfVolume> {
        let v3 = |t: &Tensor| -> Result<[f32; 3]> {
            let v = t.to_dtype(candle_core::DType::F32)?.to_vec1::<f32>()?;
            Ok([v[0], v[1], v[2]])
        };
        let s = |t: &Tensor| -> Result<f32> {
            Ok(t.to_dtype(candle_core::DType::F32)?.to_vec1::<f32>()?[0])
        };
        let sdf = match &self.shape {
            ShapeTensors::Box {
                center,
                side_lengths,
            } => Sdf::Box {
                center: v3(center)?,
                side_lengths: v3(side_lengths)?,
            },
            ShapeTensors::Sphere { center, radius } => Sdf::Sphere {
                center: v3(center)?,
                radius: s(radius)?,
            },
        };
        Ok(SdfVolume {
            sdf,
            alpha: s(&self.alpha)? as f64,
            beta: s(&self.beta)? as f64,
            rainbow: self.rainbow,
            feature: v3(&self.feature)?,
        })
    }
}

/// σ and colour at every sample. Where [`use_fused`] allows: the fused kernel when nothing is
/// tracked by autograd (rendering), else the fused kernels with backward passes of
/// `crate::sdf_volume_grad` (training); otherwise, or when the spacings are
/// tracked, `sdf_volume_tensor_ops`.
///
/// `points`: `(N, S, 3)`; `deltas`: `(N, S, 1)`. Returns σ `(N, S, 1)` and colour `(N, S, 3)`.
pub fn sdf_volume(
    points: &Tensor,
    deltas: &Tensor,
    volume: &SdfTensors,
) -> Result<(Tensor, Tensor)> {
    let tracked = needs_grad(points) || volume.tensors().into_iter().any(needs_grad);
    if !use_fused(points) || needs_grad(deltas) {
        return sdf_volume_tensor_ops(points, deltas, volume);
    }
    if tracked {
        return crate::sdf_volume_grad::sdf_volume_fused_grad(
            points,
            deltas,
            &volume.packed()?,
            volume.values()?,
        );
    }
    let fused = points.contiguous()?.apply_op2_no_bwd(
        &deltas.contiguous()?,
        &Fused(FusedSdfVolume(volume.values()?)),
    )?;
    Ok((fused.narrow(2, 0, 1)?, fused.narrow(2, 1, 3)?))
}

/// [`sdf_volume`] as Candle tensor ops (any device, differentiable in every parameter).
///
/// `points`: `(N, S, 3)`; `deltas`: `(N, S, 1)`. Returns σ `(N, S, 1)` and colour `(N, S, 3)`.
pub(crate) fn sdf_volume_tensor_ops(
    points: &Tensor,
    deltas: &Tensor,
    volume: &SdfTensors,
) -> Result<(Tensor, Tensor)> {
    let dtype = points.dtype();
    let sdf = signed_distance(&volume.shape, points)?;
    let density = sdf_to_density(
        &sdf,
        &volume.alpha.to_dtype(dtype)?,
        &volume.beta.to_dtype(dtype)?,
    )?;
    let sigma = density_to_sigma(&density, deltas)?;
    let feature = volume.feature.to_dtype(dtype)?;
    let colour = if volume.rainbow {
        points
            .broadcast_sub(&volume.center().to_dtype(dtype)?)?
            .abs()?
            .clamp(0.02f32, 0.98f32)?
            .broadcast_mul(&feature)?
    } else {
        feature.broadcast_as(points.shape())?.contiguous()?
    };
    Ok((sigma, colour))
}

/// Signed distance of each point (negative inside).
///
/// `points`: `(N, S, 3)`; returns `(N, S, 1)`.
pub(crate) fn signed_distance(shape: &ShapeTensors, points: &Tensor) -> Result<Tensor> {
    let dtype = points.dtype();
    match shape {
        ShapeTensors::Box {
            center,
            side_lengths,
        } => {
            let half = side_lengths.to_dtype(dtype)?.affine(0.5, 0.0)?;
            // q = |p − c| − s/2; sdf = ‖max(q, 0)‖ + min(max_k q_k, 0)
            let q = points
                .broadcast_sub(&center.to_dtype(dtype)?)?
                .abs()?
                .broadcast_sub(&half)?;
            let outside = safe_sqrt(&q.relu()?.sqr()?.sum_keepdim(D::Minus1)?)?;
            let inside = q.max_keepdim(D::Minus1)?.minimum(0f32)?;
            Ok(outside.add(&inside)?)
        }
        ShapeTensors::Sphere { center, radius } => Ok(safe_sqrt(
            &points
                .broadcast_sub(&center.to_dtype(dtype)?)?
                .sqr()?
                .sum_keepdim(D::Minus1)?,
        )?
        .broadcast_sub(&radius.to_dtype(dtype)?)?),
    }
}

/// Below this, [`safe_sqrt`] and [`density_to_sigma`] hold their argument (see there).
const TINY: f64 = 1e-30;

/// `√max(x, 1e-30)`: the value differs from `√x` by at most 1e-15 where `x` is 0, and the
/// gradient there is 0, as PyTorch's norm gives, instead of the `∞ · 0 = NaN` of `√x` (a point
/// inside the box has `‖max(q, 0)‖ = 0`).
fn safe_sqrt(x: &Tensor) -> Result<Tensor> {
    Ok(x.maximum(TINY)?.sqrt()?)
}

/// The homework's SDF → density: `α · (½·e^(−s/β) if s > 0 else 1 − ½·e^(s/β))`.
///
/// Written with `e^(−|s|/β)` so that neither branch overflows. `sdf`: any shape; `alpha`,
/// `beta`: `(1,)`; returns the shape of `sdf`.
pub fn sdf_to_density(sdf: &Tensor, alpha: &Tensor, beta: &Tensor) -> Result<Tensor> {
    let e = sdf.abs()?.broadcast_div(beta)?.neg()?.exp()?;
    let outside = e.affine(0.5, 0.0)?;
    let inside = e.affine(-0.5, 1.0)?;
    Ok(sdf
        .gt(0f32)?
        .where_cond(&outside, &inside)?
        .broadcast_mul(alpha)?)
}

/// The homework's density → volume density: `σ = −ln(1 − density) / Δ`.
///
/// `density`, `deltas`: `(N, S, 1)`; returns `(N, S, 1)`. Where `1 − density` is below 1e-30
/// (density 1 in float32: the homework's σ = ∞) it is held at 1e-30, so σΔ is 69: the sample
/// is opaque to within 1e-30 (the fused kernel's σ = ∞ is clamped by the renderer, see
/// `core::volume`), and the gradient there is 0 instead of the `0/0 = NaN` of `ln 0`.
pub fn density_to_sigma(density: &Tensor, deltas: &Tensor) -> Result<Tensor> {
    Ok(density
        .affine(-1.0, 1.0)?
        .maximum(TINY)?
        .log()?
        .neg()?
        .div(deltas)?)
}

/// Fused CPU kernel: points `(N, S, 3)` and deltas `(N, S, 1)` → `(N, S, 4)` = `[σ, r, g, b]`.
struct FusedSdfVolume(SdfVolume);

impl CpuKernel<2> for FusedSdfVolume {
    const NAME: &'static str = "fused-sdf-volume";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [points, deltas] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let dims = inputs[0].shape().dims();
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
                    let (sigma, f) = evaluate_point(&self.0, [p[0], p[1], p[2]], delta);
                    o.copy_from_slice(&[sigma, f[0], f[1], f[2]]);
                }
            });
        Ok((out, Shape::from((dims[0], dims[1], 4))))
    }
}

#[inline]
/// The signed distance at which [`sdf_to_density`] equals `density`: its inverse,
/// `−β·ln(2d/α)` for `d ≤ α/2` and `β·ln(2(1 − d/α))` above (0 at `α/2`). `None` unless
/// `0 < density < α` (the density only reaches 0 and α at infinite distance).
pub fn sdf_at_density(density: f64, alpha: f64, beta: f64) -> Option<f64> {
    let x = density / alpha;
    if !(x > 0.0 && x < 1.0 && beta > 0.0) {
        return None;
    }
    Some(if x <= 0.5 {
        -beta * (2.0 * x).ln()
    } else {
        beta * (2.0 * (1.0 - x)).ln()
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn sdf_at_density_inverts_the_density() {
        use crate::sdf_point::sdf_to_density_scalar;
        for s in [-0.2f32, -0.01, 0.0, 0.03, 0.15] {
            let d = sdf_to_density_scalar(s, 0.8, 0.05) as f64;
            let back = super::sdf_at_density(d, 0.8, 0.05).unwrap();
            assert!((back - s as f64).abs() < 1e-5, "{s} -> {d} -> {back}");
        }
        assert_eq!(super::sdf_at_density(0.4, 0.8, 0.05), Some(0.0));
        for bad in [0.0, 0.8, 1.0, -0.1, f64::NAN] {
            assert_eq!(super::sdf_at_density(bad, 0.8, 0.05), None);
        }
    }

    use super::*;
    use crate::{with_kernel_choice, KernelChoice};
    use candle_core::Device;
    use nerf_core::volume::MAX_OPTICAL_DEPTH;

    /// Tensors of a plain volume.
    fn tensors(v: &SdfVolume) -> SdfTensors {
        SdfTensors::from_volume(v, |_, x| Tensor::new(x, &Device::Cpu)).unwrap()
    }

    /// Tensors of a volume of shape `sdf` (α = β = 1, a white, plain colour), for the tests of
    /// the signed distance alone.
    fn shape_only(sdf: Sdf) -> SdfTensors {
        tensors(&SdfVolume {
            sdf,
            alpha: 1.0,
            beta: 1.0,
            rainbow: false,
            feature: [1.0; 3],
        })
    }

    fn values(t: &Tensor) -> Vec<f32> {
        t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
    }

    fn pts(v: &[[f32; 3]]) -> Tensor {
        let flat: Vec<f32> = v.iter().flatten().copied().collect();
        Tensor::from_vec(flat, (1, v.len(), 3), &Device::Cpu).unwrap()
    }

    /// Whether the fused σ `x` and the twin's `y` of a sample of spacing `delta` agree: the
    /// sample's opacity `1 − e^(−σΔ)`, which compositing uses, to 1e-6, and σ itself to 1e-5
    /// (relative) where the sample is not near-opaque. Near-opaque (`σΔ ≥ 5`: the density
    /// within 7e-3 of 1), the twin's `1 − density` in f32 cancels, as the homework's does,
    /// and moves σ by more; deep inside, where `1 − density` rounds to 0, the fused op gives
    /// σ = +inf (the homework's −ln 0) and the twin a finite σ whose opacity is 1 all the same.
    fn same_sigma(x: f32, y: f32, delta: f32) -> bool {
        let depth = |s: f32| (s as f64 * delta as f64).min(MAX_OPTICAL_DEPTH);
        let opacity = |s: f32| 1.0 - (-depth(s)).exp();
        let close_opacity = (opacity(x) - opacity(y)).abs() <= 1e-6;
        let close_sigma = depth(y) >= 5.0 || (x - y).abs() <= 1e-5 * y.abs().max(1.0);
        x == y || (close_opacity && close_sigma)
    }

    #[test]
    fn fused_kernel_matches_tensor_ops() {
        let dev = &Device::Cpu;
        let lengths = Tensor::arange(0f32, 17.0, dev)
            .unwrap()
            .affine(0.3, 0.0)
            .unwrap()
            .reshape((1, 17, 1))
            .unwrap()
            .broadcast_as((13, 17, 1))
            .unwrap()
            .contiguous()
            .unwrap();
        let deltas = nerf_core::volume::deltas(&lengths).unwrap();
        let spacing = values(&deltas);
        let shapes = [
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
        ];
        // Many draws: near-opaque samples and deep-inside last samples (Δ = 1e10) turn up in
        // a few of every hundred.
        for seed in 0..200 {
            let drawn = crate::test_support::uniform_values(13 * 17 * 3, seed, -2f32, 2.0);
            let points = Tensor::from_vec(drawn, (13, 17, 3), dev).unwrap();
            for (sdf, rainbow) in shapes {
                let v = tensors(&SdfVolume {
                    sdf,
                    alpha: 1.0,
                    beta: 0.05,
                    rainbow,
                    feature: [1.0, 0.5, 0.25],
                });
                let (sa, fa) = sdf_volume(&points, &deltas, &v).unwrap();
                let (sb, fb) = with_kernel_choice(KernelChoice::Generic, || {
                    sdf_volume(&points, &deltas, &v).unwrap()
                });
                assert_eq!(sa.dims(), sb.dims());
                assert_eq!(fa.dims(), fb.dims());
                for ((x, y), delta) in values(&sa).iter().zip(values(&sb)).zip(&spacing) {
                    assert!(
                        same_sigma(*x, y, *delta),
                        "seed {seed}: {x} vs {y} (Δ {delta})"
                    );
                }
                assert_eq!(values(&fa), values(&fb), "seed {seed}");
            }
        }
    }

    #[test]
    fn box_sdf_by_hand() {
        let b = shape_only(Sdf::Box {
            center: [0.0, 0.0, 0.0],
            side_lengths: [2.0, 2.0, 2.0],
        });
        let d = values(
            &signed_distance(
                &b.shape,
                &pts(&[
                    [0.0, 0.0, 0.0],
                    [3.0, 0.0, 0.0],
                    [2.0, 2.0, 1.0],
                    [0.5, 0.0, 0.0],
                ]),
            )
            .unwrap(),
        );
        let expected = [-1.0, 2.0, 2f32.sqrt(), -0.5];
        for (a, b) in d.iter().zip(expected) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
    }

    #[test]
    fn sphere_sdf_by_hand() {
        let s = shape_only(Sdf::Sphere {
            center: [1.0, 0.0, 0.0],
            radius: 0.5,
        });
        let d =
            values(&signed_distance(&s.shape, &pts(&[[1.0, 0.0, 0.0], [1.0, 2.0, 0.0]])).unwrap());
        assert_eq!(d, vec![-0.5, 1.5]);
    }

    #[test]
    fn density_matches_the_homework_formula_in_f64() {
        let (alpha, beta) = (1.0, 0.05);
        let s = [-1.0f32, -0.1, -1e-3, 0.0, 1e-3, 0.1, 1.0, 100.0, -100.0];
        let dev = &Device::Cpu;
        let t = Tensor::new(&s, dev).unwrap();
        let d = values(
            &sdf_to_density(
                &t,
                &Tensor::new(&[alpha as f32], dev).unwrap(),
                &Tensor::new(&[beta as f32], dev).unwrap(),
            )
            .unwrap(),
        );
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
        let v = tensors(&SdfVolume {
            sdf: Sdf::Box {
                center: [0.0, 0.0, 0.0],
                side_lengths: [1.0, 1.0, 1.0],
            },
            alpha: 1.0,
            beta: 0.05,
            rainbow: true,
            feature: [1.0, 1.0, 1.0],
        });
        let points = pts(&[[0.5, -2.0, 0.0], [0.0, 0.0, 0.0]]);
        let lengths = Tensor::new(&[1f32, 2.0], &Device::Cpu)
            .unwrap()
            .reshape((1, 2, 1))
            .unwrap();
        let deltas = nerf_core::volume::deltas(&lengths).unwrap();
        let (sigma, colour) = sdf_volume(&points, &deltas, &v).unwrap();
        assert_eq!(colour.dims(), &[1, 2, 3]);
        assert_eq!(sigma.dims(), &[1, 2, 1]);
        assert_eq!(values(&colour), vec![0.5, 0.98, 0.02, 0.02, 0.02, 0.02]);
    }
}
