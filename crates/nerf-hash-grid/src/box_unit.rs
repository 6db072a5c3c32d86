//! Points mapped from an axis-aligned box to [0, 1]³, and whether each lies in the box: one
//! multi-threaded pass over the points on the CPU, where the tensor-op twin
//! (`box_unit_tensor_ops`) is nine Candle ops, each its own pass over the points (on one
//! thread, as the binary runs Candle's element-wise ops), a share of a hash-grid frame worth
//! a kernel of its own (docs/speed-and-report.md).

use candle_core::{DType, Shape, Tensor};
use rayon::prelude::*;

use nerf_kernels::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use nerf_kernels::use_fused;

/// Points per task.
const POINTS_PER_TASK: usize = 4096;

/// The unit coordinates `(p − lo)·scale` of `points` `(M, 3)` (`scale` = 1 / the box's size
/// per axis): `(M, 3)`, with the gradient `scale·g` to `points` when autograd tracks them; and
/// `(M, 1)` 1 where all three coordinates lie in [0, 1] (faces included), else 0 (also for
/// NaN), with no gradient. Fused on the CPU for f32; `box_unit_tensor_ops` elsewhere.
pub fn box_unit(
    points: &Tensor,
    lo: [f32; 3],
    scale: [f32; 3],
) -> candle_core::Result<(Tensor, Tensor)> {
    if !use_fused(points) {
        return box_unit_tensor_ops(points, lo, scale);
    }
    let points = points.contiguous()?;
    let op = Fused(BoxUnit { lo, scale });
    let unit = match points.track_op() {
        true => points.apply_op1(op)?,
        false => points.apply_op1_no_bwd(&op)?,
    };
    let inside = unit.apply_op1_no_bwd(&Fused(Inside))?;
    Ok((unit, inside))
}

/// The tensor-op twin of [`box_unit`] (any device and dtype).
pub(crate) fn box_unit_tensor_ops(
    points: &Tensor,
    lo: [f32; 3],
    scale: [f32; 3],
) -> candle_core::Result<(Tensor, Tensor)> {
    let dev = points.device();
    let lo = Tensor::new(&[lo], dev)?.to_dtype(points.dtype())?;
    let scale = Tensor::new(&[scale], dev)?.to_dtype(points.dtype())?;
    let unit = points.broadcast_sub(&lo)?.broadcast_mul(&scale)?;
    let inside = (unit.ge(0.0)?.to_dtype(DType::F32)? * unit.le(1.0)?.to_dtype(DType::F32)?)?
        .min_keepdim(1)?
        .to_dtype(points.dtype())?;
    Ok((unit, inside))
}

/// `(q − lo)·scale` of one point `q` (3 values).
#[inline]
fn unit_point(q: &[f32], lo: [f32; 3], scale: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|k| (q[k] - lo[k]) * scale[k])
}

/// 1 when the three values `u` all lie in [0, 1], else 0 (also for NaN).
#[inline]
fn inside_flag(u: &[f32]) -> f32 {
    f32::from(u8::from(u.iter().all(|v| (0.0..=1.0).contains(v))))
}

/// [`box_unit`] on host values: the unit coordinates `(M, 3)` of `points` `(M, 3)` and the
/// inside flags `(M)`, one pass.
pub fn box_unit_values(points: &[f32], lo: [f32; 3], scale: [f32; 3]) -> (Vec<f32>, Vec<f32>) {
    let mut unit = vec![0f32; points.len()];
    let mut inside = vec![0f32; points.len() / 3];
    unit.par_chunks_mut(3 * POINTS_PER_TASK)
        .zip(inside.par_chunks_mut(POINTS_PER_TASK))
        .zip(points.par_chunks(3 * POINTS_PER_TASK))
        .for_each(|((unit, inside), p)| {
            for ((u, i), q) in unit.chunks_exact_mut(3).zip(inside).zip(p.chunks_exact(3)) {
                u.copy_from_slice(&unit_point(q, lo, scale));
                *i = inside_flag(u);
            }
        });
    (unit, inside)
}

/// `(p − lo)·scale`, row by row.
struct BoxUnit {
    lo: [f32; 3],
    scale: [f32; 3],
}

impl CpuKernel<1> for BoxUnit {
    const NAME: &'static str = "box-unit";

    fn cpu_forward(&self, [points]: [CpuInput; 1]) -> KernelOutput {
        let p = points.f32(Self::NAME)?;
        let (m, _) = points.shape().dims2()?;
        let mut unit = vec![0f32; p.len()];
        unit.par_chunks_mut(3 * POINTS_PER_TASK)
            .zip(p.par_chunks(3 * POINTS_PER_TASK))
            .for_each(|(out, p)| {
                for (u, q) in out.chunks_exact_mut(3).zip(p.chunks_exact(3)) {
                    u.copy_from_slice(&unit_point(q, self.lo, self.scale));
                }
            });
        Ok((unit, Shape::from((m, 3))))
    }

    fn gradients(&self, [points]: [&Tensor; 1], grad: &Tensor) -> KernelGradients<1> {
        let scale = Tensor::new(&[self.scale], points.device())?;
        Ok([Some(grad.broadcast_mul(&scale)?)])
    }
}

/// 1 where a row's three values lie in [0, 1], else 0.
struct Inside;

impl CpuKernel<1> for Inside {
    const NAME: &'static str = "box-inside";

    fn cpu_forward(&self, [unit]: [CpuInput; 1]) -> KernelOutput {
        let u = unit.f32(Self::NAME)?;
        let (m, _) = unit.shape().dims2()?;
        let mut inside = vec![0f32; m];
        inside
            .par_chunks_mut(POINTS_PER_TASK)
            .zip(u.par_chunks(3 * POINTS_PER_TASK))
            .for_each(|(out, u)| {
                for (o, q) in out.iter_mut().zip(u.chunks_exact(3)) {
                    *o = inside_flag(q);
                }
            });
        Ok((inside, Shape::from((m, 1))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};
    use nerf_kernels::test_support::{gradient_values, uniform_values, weighted_sum_gradients};
    use nerf_kernels::{with_kernel_choice, KernelChoice};

    /// Points inside, outside, on the faces and NaN, fused against the twin: the same values
    /// bit for bit, and the same gradient to the points.
    #[test]
    fn fused_matches_tensor_ops() {
        let (lo, scale) = ([-1.5f32, -1.0, 0.5], [1.0 / 3.0, 0.5, 0.5]);
        let mut p = uniform_values(3 * 5000, 7, -3f32, 3.0);
        p.extend([-1.5, -1.0, 0.5, 1.5, 1.0, 2.5, f32::NAN, 0.0, 0.6]);
        let m = p.len() / 3;
        let dev = Device::Cpu;
        let weight = Tensor::from_vec(uniform_values(3 * m, 8, -1f32, 1.0), (m, 3), &dev).unwrap();
        let run = |choice| {
            with_kernel_choice(choice, || {
                let points =
                    Var::from_tensor(&Tensor::from_vec(p.clone(), (m, 3), &dev).unwrap()).unwrap();
                let (unit, inside) = box_unit(points.as_tensor(), lo, scale).unwrap();
                let grads = weighted_sum_gradients(&unit, &weight);
                (
                    unit.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                    inside.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                    gradient_values(&grads, points.as_tensor()),
                )
            })
        };
        let (fused, twin) = (run(KernelChoice::Fused), run(KernelChoice::Generic));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&fused.0), bits(&twin.0));
        assert_eq!(fused.1, twin.1);
        assert_eq!(bits(&fused.2), bits(&twin.2));
        // The faces count as inside, NaN and points past a face as outside.
        assert_eq!(&fused.1[m - 3..], [1.0, 1.0, 0.0]);
        let inside = fused.1.iter().filter(|&&v| v == 1.0).count();
        assert!(inside > 100 && inside < m - 100, "{inside} of {m} inside");
    }
}
