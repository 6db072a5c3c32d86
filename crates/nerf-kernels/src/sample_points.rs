//! Sample points along rays, `o + t·d`: a fused CPU pass and its tensor-op twin.

use anyhow::Result;
use candle_core::{Shape, Tensor};
use rayon::prelude::*;

use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelOutput};
use crate::{needs_grad, use_fused};

/// `origins[:, None] + lengths · directions[:, None]`. Where [`use_fused`] allows and no input
/// is tracked by autograd this is one multi-threaded pass with no backward (rays and lengths
/// are never trained); otherwise the differentiable twin `sample_points_tensor_ops`.
///
/// `origins`, `directions`: `(N, 3)`; `lengths`: `(N, S, 1)`; returns `(N, S, 3)`.
pub fn sample_points(origins: &Tensor, directions: &Tensor, lengths: &Tensor) -> Result<Tensor> {
    if use_fused(origins) && ![origins, directions, lengths].into_iter().any(needs_grad) {
        return Ok(origins.contiguous()?.apply_op3_no_bwd(
            &directions.contiguous()?,
            &lengths.contiguous()?,
            &Fused(SamplePointsKernel),
        )?);
    }
    sample_points_tensor_ops(origins, directions, lengths)
}

/// [`sample_points`] as Candle broadcast ops (any device and dtype, differentiable).
///
/// `origins`, `directions`: `(N, 3)`; `lengths`: `(N, S, 1)`. Returns points `(N, S, 3)`.
pub(crate) fn sample_points_tensor_ops(
    origins: &Tensor,
    directions: &Tensor,
    lengths: &Tensor,
) -> Result<Tensor> {
    let (n, s, _) = lengths.dims3()?;
    let o = origins.unsqueeze(1)?.broadcast_as((n, s, 3))?;
    let d = directions.unsqueeze(1)?.broadcast_as((n, s, 3))?;
    Ok(o.add(&d.broadcast_mul(lengths)?)?)
}

struct SamplePointsKernel;

impl CpuKernel<3> for SamplePointsKernel {
    const NAME: &'static str = "sample-points";

    fn cpu_forward(&self, inputs: [CpuInput; 3]) -> KernelOutput {
        let [o, d, t] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let (n, s, _) = inputs[2].shape().dims3()?;
        let mut out = vec![0f32; n * s * 3];
        out.par_chunks_mut(s * 3).enumerate().for_each(|(r, p)| {
            for (i, q) in p.chunks_exact_mut(3).enumerate() {
                let ti = t[r * s + i];
                for k in 0..3 {
                    q[k] = o[r * 3 + k] + ti * d[r * 3 + k];
                }
            }
        });
        Ok((out, Shape::from((n, s, 3))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::gradient_values;
    use candle_core::{Device, Var};

    #[test]
    fn fused_points_match_broadcast_ops() {
        let dev = &Device::Cpu;
        let o = Tensor::randn(0f32, 1.0, (35, 3), dev).unwrap();
        let d = Tensor::randn(0f32, 1.0, (35, 3), dev).unwrap();
        let t = Tensor::rand(0f32, 4.0, (35, 11, 1), dev).unwrap();
        let fused = sample_points(&o, &d, &t).unwrap();
        let generic = sample_points_tensor_ops(&o, &d, &t).unwrap();
        let diff = nerf_core::compare::max_abs_difference(&fused, &generic).unwrap();
        assert!(diff < 1e-6, "{diff}");
    }

    #[test]
    fn tracked_inputs_take_the_differentiable_path() {
        let dev = &Device::Cpu;
        let o = Var::from_tensor(&Tensor::randn(0f32, 1.0, (4, 3), dev).unwrap()).unwrap();
        let d = Tensor::randn(0f32, 1.0, (4, 3), dev).unwrap();
        let t = Tensor::rand(0f32, 4.0, (4, 5, 1), dev).unwrap();
        let grads = sample_points(&o, &d, &t)
            .unwrap()
            .sum_all()
            .unwrap()
            .backward()
            .unwrap();
        // d(Σ points)/d(origin) = S per coordinate.
        let g = gradient_values(&grads, &o);
        assert!(g.iter().all(|&v| (v - 5.0).abs() < 1e-6));
    }
}
