//! Adding a bias, or a per-ray term, to the rows of an activation matrix on the CPU, with the
//! gradient of the added term summed in one multi-threaded pass over the rows (Candle's
//! broadcast-add backward reduces column by column, a visible share of a training step;
//! measured: docs/speed-and-report.md#bias-gradients).
//! Elsewhere (another device or dtype, or generic kernels chosen) the Candle ops run.

use candle_core::{Shape, Tensor};
use rayon::prelude::*;

use crate::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use crate::use_fused;

const ROWS_PER_TASK: usize = 512;

/// Sums of the columns of `x` `(M, H)`: `(H)`. On the CPU one multi-threaded pass over the
/// rows (Candle's `sum(0)` walks the matrix column by column); elsewhere `sum(0)`.
pub(crate) fn column_sum(x: &Tensor) -> candle_core::Result<Tensor> {
    if use_fused(x) {
        x.contiguous()?.apply_op1_no_bwd(&Fused(ColumnSum))
    } else {
        x.sum(0)
    }
}

struct ColumnSum;

impl CpuKernel<1> for ColumnSum {
    const NAME: &'static str = "column-sum";

    fn cpu_forward(&self, [input]: [CpuInput; 1]) -> KernelOutput {
        let x = input.f32(Self::NAME)?;
        let (_, h) = input.shape().dims2()?;
        let sum = x
            .par_chunks(ROWS_PER_TASK * h.max(1))
            .map(|block| {
                let mut acc = vec![0f32; h];
                for row in block.chunks_exact(h) {
                    for (a, v) in acc.iter_mut().zip(row) {
                        *a += v;
                    }
                }
                acc
            })
            .reduce(
                || vec![0f32; h],
                |mut a, b| {
                    for (a, b) in a.iter_mut().zip(&b) {
                        *a += b;
                    }
                    a
                },
            );
        Ok((sum, Shape::from(h)))
    }
}

/// `x + bias` for `x` `(M, H)` and `bias` `(H)`, with the bias gradient as one
/// `column_sum` (Candle's broadcast-add backward reduces column by column). CPU f32; other
/// devices use `broadcast_add`.
pub fn bias_add(x: &Tensor, bias: &Tensor) -> candle_core::Result<Tensor> {
    if use_fused(x) {
        x.contiguous()?
            .apply_op2(&bias.contiguous()?, Fused(AddRows { group: 1 }))
    } else {
        x.broadcast_add(bias)
    }
}

#[cfg(test)]
/// `out[i] = x[i] + r[i / group]` for `x` `(N·group, C)` and `r` `(N, C)`: a per-ray term
/// added to each of the ray's samples, with its gradient summed per ray in one pass. CPU f32;
/// other devices use a broadcast add.
pub(crate) fn add_per_group(x: &Tensor, r: &Tensor, group: usize) -> candle_core::Result<Tensor> {
    if use_fused(x) {
        x.contiguous()?
            .apply_op2(&r.contiguous()?, Fused(AddRows { group }))
    } else {
        let (n, c) = r.dims2()?;
        x.reshape((n, group, c))?
            .broadcast_add(&r.unsqueeze(1)?)?
            .reshape((n * group, c))
    }
}

/// `x (N·group, C) + r (N, C)` row-group-wise; `r` `(C)` (a bias) when `group` is 1 and `r`
/// is one-dimensional.
struct AddRows {
    group: usize,
}

impl CpuKernel<2> for AddRows {
    const NAME: &'static str = "add-rows";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [x, r] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let (m, c) = inputs[0].shape().dims2()?;
        let bias = inputs[1].shape().rank() == 1;
        let expected = if bias { c } else { m / self.group.max(1) * c };
        if r.len() != expected || (!bias && m % self.group.max(1) != 0) {
            candle_core::bail!("add-rows: {} values to add to {m}×{c}", r.len());
        }
        let group = self.group.max(1);
        let mut out = vec![0f32; m * c];
        out.par_chunks_mut(ROWS_PER_TASK * c)
            .zip(x.par_chunks(ROWS_PER_TASK * c))
            .enumerate()
            .for_each(|(task, (o, x))| {
                for (k, (o, x)) in o.chunks_exact_mut(c).zip(x.chunks_exact(c)).enumerate() {
                    let row = task * ROWS_PER_TASK + k;
                    let add = if bias {
                        r
                    } else {
                        &r[row / group * c..(row / group + 1) * c]
                    };
                    for ((o, x), a) in o.iter_mut().zip(x).zip(add) {
                        *o = x + a;
                    }
                }
            });
        Ok((out, Shape::from((m, c))))
    }

    fn gradients(&self, [_x, r]: [&Tensor; 2], grad: &Tensor) -> KernelGradients<2> {
        let grad_r = if r.rank() == 1 {
            column_sum(grad)?
        } else {
            let (n, c) = r.dims2()?;
            let g = grad.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
            let group = self.group.max(1);
            let mut sums = vec![0f32; n * c];
            sums.par_chunks_mut(c)
                .zip(g.par_chunks(group * c))
                .for_each(|(s, rows)| {
                    for row in rows.chunks_exact(c) {
                        for (s, v) in s.iter_mut().zip(row) {
                            *s += v;
                        }
                    }
                });
            Tensor::from_vec(sums, (n, c), r.device())?
        };
        Ok([Some(grad.clone()), Some(grad_r)])
    }
}

#[cfg(test)]
mod add_tests {
    use super::*;
    use crate::test_support::weighted_sum_gradients;
    use candle_core::{Device, Var};

    #[test]
    fn bias_and_per_group_adds_match_broadcast_autodiff() {
        let dev = Device::Cpu;
        let x = Var::randn(0f32, 1.0, (12, 5), &dev).unwrap();
        let b = Var::randn(0f32, 1.0, 5, &dev).unwrap();
        let r = Var::randn(0f32, 1.0, (4, 5), &dev).unwrap();
        let w = Tensor::randn(0f32, 1.0, (12, 5), &dev).unwrap();
        let fast = add_per_group(&bias_add(&x, &b).unwrap(), &r, 3).unwrap();
        let slow = x
            .broadcast_add(&b)
            .unwrap()
            .reshape((4, 3, 5))
            .unwrap()
            .broadcast_add(&r.unsqueeze(1).unwrap())
            .unwrap()
            .reshape((12, 5))
            .unwrap();
        let diff = |a: &Tensor, c: &Tensor| nerf_core::compare::max_abs_difference(a, c).unwrap();
        assert!(diff(&fast, &slow) < 1e-6);
        let gf = weighted_sum_gradients(&fast, &w);
        let gs = weighted_sum_gradients(&slow, &w);
        for v in [&x, &b, &r] {
            let (a, c) = (
                gf.get(v.as_tensor()).unwrap(),
                gs.get(v.as_tensor()).unwrap(),
            );
            assert!(diff(a, c) < 1e-5, "{}", diff(a, c));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::{gradient_values, weighted_sum_gradients};
    use candle_core::DType;

    #[test]
    fn column_sum_matches_candle() {
        for (m, h) in [(1, 1), (3, 5), (2000, 7), (1025, 128)] {
            let x = Tensor::randn(0f32, 1.0, (m, h), &candle_core::Device::Cpu).unwrap();
            let fast = column_sum(&x).unwrap().to_vec1::<f32>().unwrap();
            let slow = x
                .to_dtype(DType::F64)
                .unwrap()
                .sum(0)
                .unwrap()
                .to_vec1::<f64>()
                .unwrap();
            for (a, b) in fast.iter().zip(&slow) {
                assert!((*a as f64 - b).abs() < 1e-4 * (m as f64).sqrt(), "{a} {b}");
            }
        }
    }
    use candle_core::{Device, Var};

    #[test]
    fn bias_then_relu_matches_candle_ops_forward_and_backward() {
        let x = Var::new(
            &[
                [0.5f32, -1.0, 2.0],
                [-0.2, 0.3, -3.0],
                [1.0, 1.0, 1.0],
                [0.0, -0.5, 0.25],
            ],
            &Device::Cpu,
        )
        .unwrap();
        let b = Var::new(&[0.1f32, 0.4, -1.5], &Device::Cpu).unwrap();
        let w = Tensor::new(&[[1.0f32, -2.0, 3.0]], &Device::Cpu).unwrap();
        let fused = bias_add(x.as_tensor(), b.as_tensor())
            .unwrap()
            .relu()
            .unwrap();
        let reference = x
            .as_tensor()
            .broadcast_add(b.as_tensor())
            .unwrap()
            .relu()
            .unwrap();
        assert_eq!(
            fused.to_vec2::<f32>().unwrap(),
            reference.to_vec2::<f32>().unwrap()
        );
        let gf = weighted_sum_gradients(&fused, &w);
        let gr = weighted_sum_gradients(&reference, &w);
        for v in [&x, &b] {
            assert_eq!(gradient_values(&gf, v), gradient_values(&gr, v));
        }
    }
}
