//! Adam for a hash table `(R, F)`, updating only the rows a step touched (instant-ngp's
//! behaviour, tiny-cuda-nn's Adam on the encoding): an untouched row keeps its values and its
//! moments (they do not decay), and each row counts its own steps for the bias corrections.
//! On a touched row the update is exactly [`crate::adam::Adam`]'s (PyTorch's) for that row.
//!
//! The row update itself is a kernel ([`nerf_kernels::sparse_adam`]): in place on the CPU, or
//! through tensor ops on any other device.

use std::collections::HashMap;

use anyhow::{ensure, Context, Result};
use candle_core::{DType, Tensor, Var};

use nerf_kernels::sparse_adam::{nonzero_rows, AdamConstants, RowAdamState};

/// Sparse Adam's hyper-parameters and per-row state.
pub(crate) struct SparseAdam {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay (0.9).
    pub beta1: f64,
    /// Second-moment decay (0.99 in instant-ngp; 0.999 as PyTorch by default here).
    pub beta2: f64,
    /// Denominator term (instant-ngp uses 1e-15; 1e-8 as PyTorch by default here).
    pub eps: f64,
    name: String,
    var: Var,
    state: RowAdamState,
}

impl SparseAdam {
    /// Sparse Adam for `var` `(R, F)`, saved under `name`, PyTorch's defaults.
    pub(crate) fn new(name: &str, var: Var, lr: f64) -> Result<Self> {
        var.dims2().context("sparse Adam needs a 2-D parameter")?;
        let state = RowAdamState::new(var.as_tensor())?;
        Ok(Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            name: name.to_string(),
            var,
            state,
        })
    }

    fn constants(&self) -> AdamConstants {
        AdamConstants {
            lr: self.lr,
            beta1: self.beta1,
            beta2: self.beta2,
            eps: self.eps,
        }
    }

    /// Updates the `rows` (row indices, any order, no repeats) of the parameter from its
    /// gradient `grad` `(R, F)`; every other row is left exactly as it was.
    pub(crate) fn step(&self, grad: &Tensor, rows: &[u32]) -> Result<()> {
        self.state.update(&self.var, grad, rows, self.constants())
    }

    /// [`SparseAdam::step`] with the gradient as the `R·F` values of a row-major `(R, F)`
    /// buffer.
    pub(crate) fn step_rows(&self, g: &[f32], rows: &[u32]) -> Result<()> {
        self.state
            .update_from_values(&self.var, g, rows, self.constants())
    }

    /// The parameter this optimiser updates.
    pub(crate) fn var(&self) -> &Var {
        &self.var
    }

    /// Updates the rows of the parameter whose gradient in `grad` `(R, F)` is not all zero
    /// (tiny-cuda-nn's rule for the hash encoding: a parameter with an exactly zero gradient is
    /// left alone, value and moments) and returns how many rows that was.
    pub(crate) fn step_nonzero(&self, grad: &Tensor) -> Result<usize> {
        let rows = nonzero_rows(grad)?;
        self.step(grad, &rows)?;
        Ok(rows.len())
    }

    /// State tensors: `adam.exp_avg.<name>`, `adam.exp_avg_sq.<name>` `(R, F)` and
    /// `adam.row_steps.<name>` `(R,)` u32.
    pub(crate) fn state_tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let (m, v, steps) = self.state.tensors(&self.var)?;
        Ok(vec![
            (format!("adam.exp_avg.{}", self.name), m),
            (format!("adam.exp_avg_sq.{}", self.name), v),
            (format!("adam.row_steps.{}", self.name), steps),
        ])
    }

    /// Restores the state written by [`SparseAdam::state_tensors`] (an error names a missing or
    /// misshapen tensor).
    pub(crate) fn load_state(&self, tensors: &HashMap<String, Tensor>) -> Result<()> {
        let get = |key: String, dims: &[usize], dtype: DType| -> Result<Tensor> {
            let t = tensors
                .get(&key)
                .with_context(|| format!("checkpoint lacks optimizer tensor {key}"))?;
            ensure!(
                t.dims() == dims,
                "checkpoint tensor {key} has shape {:?}, the model needs {dims:?}",
                t.dims()
            );
            Ok(t.to_dtype(dtype)?)
        };
        let dims = self.var.dims();
        let m = get(format!("adam.exp_avg.{}", self.name), dims, DType::F32)?;
        let v = get(format!("adam.exp_avg_sq.{}", self.name), dims, DType::F32)?;
        let steps = get(
            format!("adam.row_steps.{}", self.name),
            &dims[..1],
            DType::U32,
        )?;
        self.state.load(&m, &v, &steps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adam::Adam;
    use candle_core::Device;

    #[test]
    fn touched_rows_follow_dense_adam_and_others_stay() {
        let dev = Device::Cpu;
        let init: Vec<f32> = (0..12).map(|i| i as f32 * 0.1 - 0.5).collect();
        let sparse_p =
            Var::from_tensor(&Tensor::from_vec(init.clone(), (6, 2), &dev).unwrap()).unwrap();
        let sparse = SparseAdam::new("t", sparse_p.clone(), 0.05).unwrap();
        // Dense Adam on a copy holding only the touched rows {1, 4} (always touched here).
        let touched = [1u32, 4];
        let dense_init: Vec<f32> = [2, 3, 8, 9].iter().map(|&i| init[i]).collect();
        let dense_p =
            Var::from_tensor(&Tensor::from_vec(dense_init, (2, 2), &dev).unwrap()).unwrap();
        let mut dense = Adam::new(vec![("t".into(), dense_p.clone())], 0.05).unwrap();
        let target = Tensor::new(&[[1f32, -2.0], [0.5, 3.0]], &dev).unwrap();
        let idx = Tensor::new(&touched, &dev).unwrap();
        for _ in 0..5 {
            // loss = Σ (p[touched] − target)²: gradient only on the touched rows.
            let loss = |p: &Tensor| {
                (p - &target)
                    .unwrap()
                    .sqr()
                    .unwrap()
                    .sum_all()
                    .unwrap()
                    .backward()
                    .unwrap()
            };
            let g = loss(&sparse_p.as_tensor().index_select(&idx, 0).unwrap());
            sparse
                .step(g.get(sparse_p.as_tensor()).unwrap(), &touched)
                .unwrap();
            dense.step(&loss(dense_p.as_tensor())).unwrap();
        }
        let got = sparse_p.as_tensor().to_vec2::<f32>().unwrap();
        let want = dense_p.as_tensor().to_vec2::<f32>().unwrap();
        for (k, &r) in touched.iter().enumerate() {
            for c in 0..2 {
                assert!((got[r as usize][c] - want[k][c]).abs() < 1e-6, "row {r}");
            }
        }
        for r in [0usize, 2, 3, 5] {
            assert_eq!(got[r], init[r * 2..r * 2 + 2], "untouched row {r} moved");
        }
        // The state round-trips; a bad row is an error.
        let saved: HashMap<String, Tensor> = sparse.state_tensors().unwrap().into_iter().collect();
        let other = SparseAdam::new("t", sparse_p.clone(), 0.05).unwrap();
        other.load_state(&saved).unwrap();
        assert_eq!(
            saved["adam.row_steps.t"].to_vec1::<u32>().unwrap(),
            [0, 5, 0, 0, 5, 0]
        );
        let zeros = sparse_p.zeros_like().unwrap();
        assert!(sparse.step(&zeros, &[6]).is_err());
    }
}
