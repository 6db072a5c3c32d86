//! Adam for a hash table `(R, F)`, updating only the rows a step touched (instant-ngp's
//! behaviour, tiny-cuda-nn's Adam on the encoding): an untouched row keeps its values and its
//! moments (they do not decay), and each row counts its own steps for the bias corrections.
//! On a touched row the update is exactly [`crate::train::adam::Adam`]'s (PyTorch's) for that row.
//!
//! The table is updated in place on the CPU (no copy of the table per step); the gradient is
//! read where autograd left it.

use std::collections::HashMap;
use std::sync::Mutex;

use rayon::prelude::*;

use anyhow::{bail, ensure, Context, Result};
use candle_core::{CpuStorage, DType, InplaceOp1, Layout, Storage, Tensor, Var};

use crate::kernels::storage::contiguous_f32;

/// Sparse Adam's hyper-parameters and per-row state.
pub struct SparseAdam {
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
    width: usize,
    state: Mutex<RowState>,
}

struct RowState {
    m: Vec<f32>,
    v: Vec<f32>,
    steps: Vec<u32>,
}

impl SparseAdam {
    /// Sparse Adam for `var` `(R, F)` (f32 on the CPU), saved under `name`, PyTorch's defaults.
    pub fn new(name: &str, var: Var, lr: f64) -> Result<Self> {
        let (rows, width) = var.dims2().context("sparse Adam needs a 2-D parameter")?;
        ensure!(
            var.device().is_cpu() && var.dtype() == DType::F32,
            "sparse Adam runs on f32 CPU parameters ({name} is {:?} on {:?})",
            var.dtype(),
            var.device()
        );
        Ok(Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            name: name.to_string(),
            var,
            width,
            state: Mutex::new(RowState {
                m: vec![0.0; rows * width],
                v: vec![0.0; rows * width],
                steps: vec![0; rows],
            }),
        })
    }

    /// Updates the `rows` (row indices, any order, no repeats) of the parameter from its
    /// gradient `grad` `(R, F)`; every other row is left exactly as it was.
    pub fn step(&self, grad: &Tensor, rows: &[u32]) -> Result<()> {
        ensure!(
            grad.dims() == self.var.dims(),
            "sparse Adam: gradient {:?} for parameter {:?}",
            grad.dims(),
            self.var.dims()
        );
        let grad = grad.to_dtype(DType::F32)?.contiguous()?;
        let (storage, layout) = grad.storage_and_layout();
        let Storage::Cpu(cpu) = &*storage else {
            bail!("sparse Adam: the gradient must be on the CPU");
        };
        self.step_rows(contiguous_f32(cpu, layout, "sparse-adam")?, rows)
    }

    /// [`SparseAdam::step`] with the gradient as the `R·F` values of a row-major `(R, F)`
    /// buffer.
    pub fn step_rows(&self, g: &[f32], rows: &[u32]) -> Result<()> {
        ensure!(
            g.len() == self.var.elem_count(),
            "sparse Adam: {} gradient values for a parameter of {}",
            g.len(),
            self.var.elem_count()
        );
        let n_rows = self.var.dim(0)?;
        if let Some(bad) = rows.iter().find(|&&r| r as usize >= n_rows) {
            bail!("sparse Adam: row {bad} of a {n_rows}-row parameter");
        }
        let op = Update {
            adam: self,
            grad: g,
            rows,
        };
        self.var.as_tensor().inplace_op1(&op)?;
        Ok(())
    }

    /// The parameter this optimiser updates.
    pub fn var(&self) -> &Var {
        &self.var
    }

    /// Updates the rows of the parameter whose gradient in `grad` `(R, F)` is not all zero
    /// (tiny-cuda-nn's rule for the hash encoding: a parameter with an exactly zero gradient is
    /// left alone, value and moments) and returns how many rows that was.
    pub fn step_nonzero(&self, grad: &Tensor) -> Result<usize> {
        let g = grad.to_dtype(DType::F32)?.contiguous()?;
        let rows = {
            let (storage, layout) = g.storage_and_layout();
            let Storage::Cpu(cpu) = &*storage else {
                bail!("sparse Adam: the gradient must be on the CPU");
            };
            nonzero_rows(contiguous_f32(cpu, layout, "sparse-adam")?, self.width)
        };
        self.step(&g, &rows)?;
        Ok(rows.len())
    }

    /// State tensors: `adam.exp_avg.<name>`, `adam.exp_avg_sq.<name>` `(R, F)` and
    /// `adam.row_steps.<name>` `(R,)` u32.
    pub fn state_tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let s = self.state.lock().expect("sparse Adam lock");
        let shape = self.var.shape();
        let dev = self.var.device();
        Ok(vec![
            (
                format!("adam.exp_avg.{}", self.name),
                Tensor::from_slice(&s.m, shape, dev)?,
            ),
            (
                format!("adam.exp_avg_sq.{}", self.name),
                Tensor::from_slice(&s.v, shape, dev)?,
            ),
            (
                format!("adam.row_steps.{}", self.name),
                Tensor::from_slice(&s.steps, s.steps.len(), dev)?,
            ),
        ])
    }

    /// Restores the state written by [`SparseAdam::state_tensors`] (an error names a missing or
    /// misshapen tensor).
    pub fn load_state(&self, tensors: &HashMap<String, Tensor>) -> Result<()> {
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
        let mut s = self.state.lock().expect("sparse Adam lock");
        s.m = m.flatten_all()?.to_vec1()?;
        s.v = v.flatten_all()?.to_vec1()?;
        s.steps = steps.to_vec1()?;
        Ok(())
    }
}

/// The rows (of `width` values each) of `grad` holding a non-zero value, in order.
pub fn nonzero_rows(grad: &[f32], width: usize) -> Vec<u32> {
    grad.par_chunks(ROWS_PER_TASK * width)
        .enumerate()
        .flat_map_iter(|(task, chunk)| {
            chunk
                .chunks_exact(width)
                .enumerate()
                .filter(|(_, row)| row.iter().any(|&v| v != 0.0))
                .map(move |(i, _)| (task * ROWS_PER_TASK + i) as u32)
        })
        .collect()
}

/// Rows per task of the update.
const ROWS_PER_TASK: usize = 1 << 14;

/// The in-place update of the touched rows.
struct Update<'a> {
    adam: &'a SparseAdam,
    grad: &'a [f32],
    rows: &'a [u32],
}

impl InplaceOp1 for Update<'_> {
    fn name(&self) -> &'static str {
        "sparse-adam"
    }

    fn cpu_fwd(&self, storage: &mut CpuStorage, layout: &Layout) -> candle_core::Result<()> {
        let Some((start, end)) = layout.contiguous_offsets() else {
            candle_core::bail!("sparse-adam: the parameter must be contiguous");
        };
        let CpuStorage::F32(data) = storage else {
            candle_core::bail!("sparse-adam: the parameter must be f32");
        };
        let p = &mut data[start..end];
        let a = self.adam;
        let f = a.width;
        let mut s = a.state.lock().expect("sparse Adam lock");
        let RowState { m, v, steps } = &mut *s;
        // Rows bucketed by block of ROWS_PER_TASK (a counting sort), so that each task owns
        // its block's slice of the parameter and state.
        let n_blocks = steps.len().div_ceil(ROWS_PER_TASK);
        let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); n_blocks];
        for &r in self.rows {
            buckets[r as usize / ROWS_PER_TASK].push(r);
        }
        let (b1, b2, lr, eps) = (a.beta1, a.beta2, a.lr, a.eps);
        let grad = self.grad;
        // Bias corrections by step count, up to the largest count after this step (a row's
        // count is at most the optimiser's steps).
        let most = 1 + self
            .rows
            .iter()
            .map(|&r| steps[r as usize])
            .max()
            .unwrap_or(0) as usize;
        let corrections: Vec<(f64, f64)> = (0..=most)
            .map(|t| (1.0 - b1.powi(t as i32), (1.0 - b2.powi(t as i32)).sqrt()))
            .collect();
        p.par_chunks_mut(ROWS_PER_TASK * f)
            .zip(m.par_chunks_mut(ROWS_PER_TASK * f))
            .zip(v.par_chunks_mut(ROWS_PER_TASK * f))
            .zip(steps.par_chunks_mut(ROWS_PER_TASK))
            .zip(buckets.par_iter())
            .enumerate()
            .for_each(|(block, ((((p, m), v), steps), rows))| {
                let first = block * ROWS_PER_TASK;
                for &r in rows {
                    let local = r as usize - first;
                    steps[local] += 1;
                    let (bias1, bias2_sqrt) = corrections[steps[local] as usize];
                    for k in 0..f {
                        let (i, g) = (local * f + k, grad[r as usize * f + k] as f64);
                        let mk = b1 * m[i] as f64 + (1.0 - b1) * g;
                        let vk = b2 * v[i] as f64 + (1.0 - b2) * g * g;
                        m[i] = mk as f32;
                        v[i] = vk as f32;
                        let denom = (vk as f32).sqrt() as f64 / bias2_sqrt + eps;
                        p[i] -= (lr / bias1 * mk as f32 as f64 / denom) as f32;
                    }
                }
            });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::adam::Adam;
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
