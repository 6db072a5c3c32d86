//! Sparse Adam's row update on a table `(R, F)`: only the listed rows move, each with its own
//! step count for the bias corrections; an unlisted row keeps its values and moments.
//!
//! Two paths, chosen from the table when the state is made ([`RowAdamState::new`]):
//!
//! * fused: the table updated in place on the CPU (no copy of the table per step), the moments
//!   in host memory, the maths in f64 per element;
//! * twin: Candle tensor ops on any device (`index_select` of the rows, the same formulas,
//!   `scatter_set` back), the moments as tensors beside the table.
//!
//! A test holds the two equal over several steps of overlapping row sets.

use std::sync::Mutex;

use anyhow::{bail, ensure, Result};
use candle_core::{CpuStorage, DType, InplaceOp1, Layout, Storage, Tensor, Var};
use rayon::prelude::*;

use crate::storage::contiguous_f32;
use crate::use_fused;

/// Adam's constants for one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamConstants {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator term.
    pub eps: f64,
}

/// The moments `(R, F)` and per-row step counts `(R,)` of a table's sparse Adam.
pub struct RowAdamState {
    width: usize,
    state: Mutex<Moments>,
}

enum Moments {
    /// The fused path's state, row-major in host memory.
    Host {
        m: Vec<f32>,
        v: Vec<f32>,
        steps: Vec<u32>,
    },
    /// The twin's state: `m`, `v` `(R, F)` and `steps` `(R,)` (f32, exact to 2²⁴ steps) on the
    /// table's device and in its dtype.
    Device { m: Tensor, v: Tensor, steps: Tensor },
}

impl RowAdamState {
    /// Zero state for `table` `(R, F)`: the fused path where [`use_fused`] allows (f32 on the
    /// CPU, fused kernels chosen), else the twin.
    pub fn new(table: &Tensor) -> Result<Self> {
        let (rows, width) = table.dims2()?;
        let moments = if use_fused(table) {
            Moments::Host {
                m: vec![0.0; rows * width],
                v: vec![0.0; rows * width],
                steps: vec![0; rows],
            }
        } else {
            Moments::Device {
                m: table.zeros_like()?,
                v: table.zeros_like()?,
                steps: Tensor::zeros(rows, table.dtype(), table.device())?,
            }
        };
        Ok(Self {
            width,
            state: Mutex::new(moments),
        })
    }

    /// Updates `rows` (indices, any order, no repeats) of `table` from its gradient `grad`
    /// `(R, F)`.
    pub fn update(&self, table: &Var, grad: &Tensor, rows: &[u32], c: AdamConstants) -> Result<()> {
        ensure!(
            grad.dims() == table.dims(),
            "sparse Adam: gradient {:?} for parameter {:?}",
            grad.dims(),
            table.dims()
        );
        let mut state = self.checked_state(table, grad.elem_count(), rows)?;
        match &mut *state {
            Moments::Host { .. } => {
                let grad = grad
                    .to_dtype(DType::F32)?
                    .to_device(&candle_core::Device::Cpu)?;
                let grad = grad.contiguous()?;
                let (storage, layout) = grad.storage_and_layout();
                let Storage::Cpu(cpu) = &*storage else {
                    bail!("sparse Adam: the gradient must be on the CPU");
                };
                let g = contiguous_f32(cpu, layout, "sparse-adam")?;
                update_host(table, &mut state, self.width, g, rows, c)
            }
            Moments::Device { m, v, steps } => {
                update_tensor_ops(table, (m, v, steps), grad, rows, c)
            }
        }
    }

    /// [`RowAdamState::update`] with the gradient as the `R·F` values of a row-major `(R, F)`
    /// host buffer (what a fused encoding leaves outside autograd).
    pub fn update_from_values(
        &self,
        table: &Var,
        g: &[f32],
        rows: &[u32],
        c: AdamConstants,
    ) -> Result<()> {
        let mut state = self.checked_state(table, g.len(), rows)?;
        match &mut *state {
            Moments::Host { .. } => update_host(table, &mut state, self.width, g, rows, c),
            Moments::Device { m, v, steps } => {
                let grad = Tensor::from_slice(g, table.shape(), table.device())?
                    .to_dtype(table.dtype())?;
                update_tensor_ops(table, (m, v, steps), &grad, rows, c)
            }
        }
    }

    /// The moments, locked, once `rows` and a gradient of `values` values are checked against
    /// `table`.
    fn checked_state(
        &self,
        table: &Var,
        values: usize,
        rows: &[u32],
    ) -> Result<std::sync::MutexGuard<'_, Moments>> {
        ensure!(
            values == table.elem_count(),
            "sparse Adam: {values} gradient values for a parameter of {}",
            table.elem_count()
        );
        check_rows(table, rows)?;
        Ok(self.state.lock().expect("sparse Adam lock"))
    }

    /// The moments `(R, F)` f32 and step counts `(R,)` u32, on `table`'s device.
    pub fn tensors(&self, table: &Var) -> Result<(Tensor, Tensor, Tensor)> {
        let state = self.state.lock().expect("sparse Adam lock");
        let (shape, dev) = (table.shape(), table.device());
        Ok(match &*state {
            Moments::Host { m, v, steps } => (
                Tensor::from_slice(m, shape, dev)?,
                Tensor::from_slice(v, shape, dev)?,
                Tensor::from_slice(steps, steps.len(), dev)?,
            ),
            Moments::Device { m, v, steps } => (
                m.to_dtype(DType::F32)?,
                v.to_dtype(DType::F32)?,
                steps.to_dtype(DType::U32)?,
            ),
        })
    }

    /// Replaces the state with `m`, `v` `(R, F)` and `steps` `(R,)` (shapes checked by the
    /// caller).
    pub fn load(&self, m: &Tensor, v: &Tensor, steps: &Tensor) -> Result<()> {
        let mut state = self.state.lock().expect("sparse Adam lock");
        match &mut *state {
            Moments::Host {
                m: hm,
                v: hv,
                steps: hs,
            } => {
                *hm = m.to_dtype(DType::F32)?.flatten_all()?.to_vec1()?;
                *hv = v.to_dtype(DType::F32)?.flatten_all()?.to_vec1()?;
                *hs = steps.to_dtype(DType::U32)?.to_vec1()?;
            }
            Moments::Device {
                m: dm,
                v: dv,
                steps: ds,
            } => {
                let like = |t: &Tensor, d: &Tensor| -> Result<Tensor> {
                    Ok(t.to_dtype(d.dtype())?.to_device(d.device())?)
                };
                (*dm, *dv, *ds) = (like(m, dm)?, like(v, dv)?, like(steps, ds)?);
            }
        }
        Ok(())
    }
}

/// An error for a row index outside the table.
fn check_rows(table: &Var, rows: &[u32]) -> Result<()> {
    let n_rows = table.dim(0)?;
    if let Some(bad) = rows.iter().find(|&&r| r as usize >= n_rows) {
        bail!("sparse Adam: row {bad} of a {n_rows}-row parameter");
    }
    Ok(())
}

/// The rows of `grad` `(R, F)` holding a non-zero value, in order.
pub fn nonzero_rows(grad: &Tensor) -> Result<Vec<u32>> {
    if use_fused(grad) {
        let g = grad.contiguous()?;
        let (storage, layout) = g.storage_and_layout();
        let Storage::Cpu(cpu) = &*storage else {
            bail!("sparse Adam: the gradient must be on the CPU");
        };
        let width = grad.dim(1)?;
        return Ok(nonzero_rows_of(
            contiguous_f32(cpu, layout, "sparse-adam")?,
            width,
        ));
    }
    let touched = grad.abs()?.sum(1)?.ne(0.0)?.to_vec1::<u8>()?;
    Ok(touched
        .iter()
        .enumerate()
        .filter(|(_, &t)| t != 0)
        .map(|(i, _)| i as u32)
        .collect())
}

/// The rows (of `width` values each) of the row-major `grad` holding a non-zero value.
fn nonzero_rows_of(grad: &[f32], width: usize) -> Vec<u32> {
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

/// Rows per task of the fused update.
const ROWS_PER_TASK: usize = 1 << 14;

/// The fused path: the table updated in place.
fn update_host(
    table: &Var,
    state: &mut Moments,
    width: usize,
    grad: &[f32],
    rows: &[u32],
    c: AdamConstants,
) -> Result<()> {
    let Moments::Host { m, v, steps } = state else {
        bail!("sparse Adam: host update on device state");
    };
    let op = Update {
        state: Mutex::new((m, v, steps)),
        width,
        grad,
        rows,
        c,
    };
    table.as_tensor().inplace_op1(&op)?;
    Ok(())
}

/// The twin: the same update through tensor ops, any device and dtype.
fn update_tensor_ops(
    table: &Var,
    (m, v, steps): (&mut Tensor, &mut Tensor, &mut Tensor),
    grad: &Tensor,
    rows: &[u32],
    c: AdamConstants,
) -> Result<()> {
    if rows.is_empty() {
        return Ok(());
    }
    let (k, f) = (rows.len(), table.dim(1)?);
    let dev = table.device();
    let index = Tensor::from_slice(rows, k, dev)?;
    let index_2d = index.unsqueeze(1)?.broadcast_as((k, f))?.contiguous()?;
    let g = grad.to_dtype(table.dtype())?.index_select(&index, 0)?;
    let m_rows = ((m.index_select(&index, 0)? * c.beta1)? + (&g * (1.0 - c.beta1))?)?;
    let v_rows = ((v.index_select(&index, 0)? * c.beta2)? + (g.sqr()? * (1.0 - c.beta2))?)?;
    let t = (steps.index_select(&index, 0)? + 1.0)?;
    // 1 − βᵗ per row, as exp(t·ln β).
    let bias = |beta: f64| -> Result<Tensor> {
        Ok(t.affine(beta.ln(), 0.0)?
            .exp()?
            .affine(-1.0, 1.0)?
            .unsqueeze(1)?)
    };
    let (bias1, bias2_sqrt) = (bias(c.beta1)?, bias(c.beta2)?.sqrt()?);
    let denom = (v_rows.sqrt()?.broadcast_div(&bias2_sqrt)? + c.eps)?;
    let step = (m_rows.broadcast_div(&bias1)? / denom)?.affine(c.lr, 0.0)?;
    let p_rows = (table.as_tensor().index_select(&index, 0)? - step)?;
    m.scatter_set(&index_2d, &m_rows, 0)?;
    v.scatter_set(&index_2d, &v_rows, 0)?;
    steps.scatter_set(&index, &t, 0)?;
    table.as_tensor().scatter_set(&index_2d, &p_rows, 0)?;
    Ok(())
}

/// `rows` split by block of [`ROWS_PER_TASK`] rows, in their order within each block: slices of
/// `rows` when it is sorted (as a fused encoding's gradient gives them), else a counting sort.
fn row_blocks(rows: &[u32], n_blocks: usize) -> Vec<std::borrow::Cow<'_, [u32]>> {
    let block = |r: u32| r as usize / ROWS_PER_TASK;
    if rows.is_sorted() {
        let mut out = Vec::with_capacity(n_blocks);
        let mut rest = rows;
        for b in 0..n_blocks {
            let end = rest.partition_point(|&r| block(r) <= b);
            let (this, next) = rest.split_at(end);
            out.push(this.into());
            rest = next;
        }
        return out;
    }
    let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); n_blocks];
    for &r in rows {
        buckets[block(r)].push(r);
    }
    buckets.into_iter().map(Into::into).collect()
}

/// The fused in-place update of the touched rows.
struct Update<'a> {
    /// `m`, `v` and the step counts (the op is called through `&self`).
    #[allow(clippy::type_complexity)]
    state: Mutex<(&'a mut Vec<f32>, &'a mut Vec<f32>, &'a mut Vec<u32>)>,
    width: usize,
    grad: &'a [f32],
    rows: &'a [u32],
    c: AdamConstants,
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
        let f = self.width;
        let mut state = self.state.lock().expect("sparse Adam lock");
        let (m, v, steps) = &mut *state;
        // Rows bucketed by block of ROWS_PER_TASK (a counting sort), so that each task owns
        // its block's slice of the parameter and state.
        let n_blocks = steps.len().div_ceil(ROWS_PER_TASK);
        let buckets = row_blocks(self.rows, n_blocks);
        let AdamConstants {
            lr,
            beta1: b1,
            beta2: b2,
            eps,
        } = self.c;
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
                for &r in rows.iter() {
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
    use crate::{with_kernel_choice, KernelChoice};
    use candle_core::Device;
    use rand::{Rng, SeedableRng};

    #[test]
    fn fused_update_matches_its_tensor_op_twin() {
        // More rows than one fused task's block, so that rows fall in several blocks.
        let (r, f) = (ROWS_PER_TASK * 2 + 40, 3);
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        let mut random =
            |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random::<f32>() - 0.5).collect() };
        let init = random(r * f);
        let dev = &Device::Cpu;
        let table =
            || Var::from_tensor(&Tensor::from_vec(init.clone(), (r, f), dev).unwrap()).unwrap();
        let (fused_table, twin_table) = (table(), table());
        let fused = RowAdamState::new(fused_table.as_tensor()).unwrap();
        let twin = with_kernel_choice(KernelChoice::Generic, || {
            RowAdamState::new(twin_table.as_tensor()).unwrap()
        });
        assert!(matches!(*fused.state.lock().unwrap(), Moments::Host { .. }));
        assert!(matches!(
            *twin.state.lock().unwrap(),
            Moments::Device { .. }
        ));
        let c = AdamConstants {
            lr: 0.05,
            beta1: 0.9,
            beta2: 0.99,
            eps: 1e-15,
        };
        let mut touched = vec![false; r];
        for step in 0..6u32 {
            // Overlapping row sets, so that rows reach different counts; every seventh row is
            // never touched. Sorted on even steps (the fused path slices them by block),
            // scrambled on odd ones (it sorts them into blocks).
            let mut rows: Vec<u32> = (0..r as u32)
                .filter(|i| (i + step) % 3 != 0 && i % 7 != 0)
                .collect();
            if step % 2 == 1 {
                rows.reverse();
            }
            for &row in &rows {
                touched[row as usize] = true;
            }
            let grad = Tensor::from_vec(random(r * f), (r, f), dev).unwrap();
            fused.update(&fused_table, &grad, &rows, c).unwrap();
            twin.update(&twin_table, &grad, &rows, c).unwrap();
        }
        let close = |a: &Tensor, b: &Tensor, what: &str| {
            let d = nerf_core::compare::max_abs_difference(a, b).unwrap();
            assert!(d < 1e-5, "{what} differs by {d}");
        };
        close(fused_table.as_tensor(), twin_table.as_tensor(), "table");
        let (fm, fv, fs) = fused.tensors(&fused_table).unwrap();
        let (tm, tv, ts) = twin.tensors(&twin_table).unwrap();
        close(&fm, &tm, "first moment");
        close(&fv, &tv, "second moment");
        assert_eq!(fs.to_vec1::<u32>().unwrap(), ts.to_vec1::<u32>().unwrap());
        // Rows never touched are exactly as they were.
        assert_eq!(
            touched.iter().filter(|t| !**t).count(),
            (0..r).filter(|i| i % 7 == 0).count()
        );
        let after = twin_table.as_tensor().to_vec2::<f32>().unwrap();
        for (row, was) in init.chunks(f).enumerate().filter(|(i, _)| !touched[*i]) {
            assert_eq!(after[row], was, "untouched row {row} moved");
        }
    }
}
