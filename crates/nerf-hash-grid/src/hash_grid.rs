//! Multiresolution hash encoding (Instant-NGP, Müller et al. 2022): `L` grids of resolutions
//! `N_l = ⌊N_min · b^l⌋`, `b = exp((ln N_max − ln N_min)/(L − 1))`, each a table of `T = 2^log2_T`
//! rows of `F` features. A point in [0, 1]³ is scaled by `N_l`; the 8 corners of its cell are
//! looked up — densely (`x + y·(N_l+1) + z·(N_l+1)²`) on coarse levels whose `(N_l+1)³ ≤ T`,
//! else hashed (`x·1 ⊕ y·2654435761 ⊕ z·805459861 mod T`, u32 arithmetic) — and their features
//! interpolated trilinearly. The output is the `L·F` interpolated features.
//!
//! The fused CPU op runs the points in parallel forward; backward it scatters the output
//! gradient into the table gradient one level per task: levels own disjoint slices of the table,
//! so there is no race and no per-thread buffer. The table gradient it returns is dense
//! (`L·T × F`, zero-initialised: autograd gives every variable a dense gradient; the
//! allocation is a fresh zero-page mapping, so only the pages a step writes are touched), and
//! The tests' `touched_rows` names the rows a step touched, which a sparse optimiser updates.
//! Its twin gathers the
//! corner rows with `index_select` and weights them with tensor ops (Candle's `index_select`
//! backward is the `index_add` scatter); corner indices and weights come from the points
//! (never trained) on the host.

use std::sync::{Arc, Mutex};

use candle_core::{DType, Shape, Tensor};
use rayon::prelude::*;

pub use crate::hash_level::{HashGridParams, Level, HASH_PRIMES};
use crate::{hash_block, hash_point_gradient};
use nerf_kernels::cpu_kernel::{CpuInput, CpuKernel, Fused, KernelGradients, KernelOutput};
use nerf_kernels::storage::host_values;
use nerf_kernels::use_fused;

/// Points per task of the fused forward pass. A task walks its points one level at a time, so
/// that its gathers stay in one level's slice of the table (2 MiB at 2^18 rows of 2 features,
/// near the size of an L2 cache) rather than hopping across all `L` slices (32 MiB) for every
/// point: random reads from one slice run several times faster than from the whole table
/// (measured: docs/speed-and-report.md#hash-table-reads).
const POINTS_PER_TASK: usize = 1024;

/// Encodes `points` `(M, 3)` (in [0, 1]³) with `table` `(L·T, F)`: `(M, L·F)`, level-major
/// (level `l`'s `F` features at columns `l·F..(l+1)·F`). The gradient flows to `table`, and
/// to `points` when autograd tracks them (`crate::hash_point_gradient`; computed
/// only then). Fused on the CPU for f32 ([`use_fused`]); `hash_encode_generic` elsewhere.
///
/// With a `sink`, the fused backward pass adds the table gradient there (touched rows only)
/// instead of returning a dense one through autograd; the twin ignores it.
pub fn hash_encode(
    points: &Tensor,
    table: &Tensor,
    params: &HashGridParams,
    sink: Option<&Arc<TableGradient>>,
) -> candle_core::Result<Tensor> {
    check_shapes(points, table, params)?;
    if use_fused(table) && points.device().is_cpu() {
        let op = Fused(HashEncode {
            params: *params,
            sink: sink.cloned(),
        });
        let points = points.to_dtype(DType::F32)?.contiguous()?;
        let table = table.contiguous()?;
        if table.track_op() || points.track_op() {
            points.apply_op2(&table, op)
        } else {
            points.apply_op2_no_bwd(&table, &op)
        }
    } else {
        hash_encode_generic(points, table, params)
    }
}

/// The table gradient of the fused encoding's backward passes, kept apart from autograd for
/// the sparse optimiser: a dense `(L·T, F)` buffer that persists between steps (allocated
/// once, zeroed lazily by the OS) and the rows written since the last [`TableGradient::take`].
/// Through Candle's autograd the same gradient costs a freshly zeroed dense tensor, then
/// another zeroed accumulator and a dense add (three passes over `L·T·F` floats per step); here
/// only touched rows are written, and they are cleared when taken.
pub struct TableGradient {
    state: Mutex<GradientState>,
}

impl std::fmt::Debug for TableGradient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TableGradient")
    }
}

struct GradientState {
    values: Vec<f32>,
    /// One bit per row, set when a backward pass writes the row: `words_per_level` words per
    /// level. Setting a bit is branch-free, where a `seen` flag with a list of first touches
    /// mispredicted often on the fine levels (measured:
    /// docs/speed-and-report.md#hash-table-reads); and the rows come out of
    /// it sorted, so the optimiser walks the table and its moments in address order.
    touched: Vec<u64>,
    words_per_level: usize,
}

impl TableGradient {
    /// An empty gradient for tables of `params`' shape.
    pub fn new(params: &HashGridParams) -> Self {
        let words_per_level = params.table_size().div_ceil(64);
        Self {
            state: Mutex::new(GradientState {
                values: vec![0.0; params.n_rows() * params.n_features],
                touched: vec![0; params.n_levels * words_per_level],
                words_per_level,
            }),
        }
    }

    /// Adds the table gradient of the encoding of `points` `(M, 3)` (in [0, 1]³) whose output
    /// gradient is `grad` `(M, L·F)`, one level per task, marking the rows written.
    pub fn add(&self, params: &HashGridParams, points: &[f32], grad: &[f32]) {
        let (levels, t, f) = (params.levels(), params.table_size(), params.n_features);
        let mut guard = self.state.lock().expect("table gradient lock");
        let GradientState {
            values,
            touched,
            words_per_level,
        } = &mut *guard;
        values
            .par_chunks_mut(t * f)
            .zip(touched.par_chunks_mut(*words_per_level))
            .zip(levels.par_iter())
            .enumerate()
            .for_each(|(l, ((d, bits), level))| {
                hash_block::scatter_points((level, l), d, bits, points, grad, f)
            });
    }

    /// Hands `f` the touched rows (into the whole table, level offsets added; sorted) and the
    /// dense gradient, then clears both.
    pub fn take<R>(&self, params: &HashGridParams, f: impl FnOnce(&[u32], &[f32]) -> R) -> R {
        let mut s = self.state.lock().expect("table gradient lock");
        let (t, width) = (params.table_size(), params.n_features);
        let GradientState {
            values,
            touched,
            words_per_level,
        } = &mut *s;
        let words = *words_per_level;
        let per_level: Vec<Vec<u32>> = touched
            .par_chunks(words)
            .enumerate()
            .map(|(l, bits)| {
                let mut rows = Vec::new();
                for (w, &word) in bits.iter().enumerate() {
                    let mut word = word;
                    while word != 0 {
                        let bit = word.trailing_zeros();
                        rows.push((l * t + w * 64) as u32 + bit);
                        word &= word - 1;
                    }
                }
                rows
            })
            .collect();
        let rows = per_level.concat();
        let out = f(&rows, values);
        values
            .par_chunks_mut(t * width)
            .zip(touched.par_chunks_mut(words))
            .zip(per_level.par_iter())
            .enumerate()
            .for_each(|(l, ((values, bits), rows))| {
                for &r in rows {
                    let r = r as usize - l * t;
                    values[r * width..(r + 1) * width].fill(0.0);
                }
                bits.fill(0);
            });
        out
    }
}

fn check_shapes(points: &Tensor, table: &Tensor, p: &HashGridParams) -> candle_core::Result<()> {
    let (_, three) = points.dims2()?;
    let (rows, f) = table.dims2()?;
    if three != 3 || rows != p.n_rows() || f != p.n_features {
        candle_core::bail!(
            "hash encoding: points {:?} and table {:?}, expected (M, 3) and ({}, {})",
            points.dims(),
            table.dims(),
            p.n_rows(),
            p.n_features
        );
    }
    Ok(())
}

/// Rows into the whole table (level offset added) and weights of every point's corners:
/// `M·L·8` of each, point-major, then level, then corner.
fn corner_rows(points: &[f32], params: &HashGridParams) -> (Vec<u32>, Vec<f32>) {
    let levels = params.levels();
    let t = params.table_size() as u32;
    let per_point = levels.len() * 8;
    let m = points.len() / 3;
    let mut rows = vec![0u32; m * per_point];
    let mut weights = vec![0f32; m * per_point];
    rows.par_chunks_mut(per_point)
        .zip(weights.par_chunks_mut(per_point))
        .zip(points.par_chunks(3))
        .for_each(|((r, w), p)| {
            for (l, level) in levels.iter().enumerate() {
                for (k, (i, wk)) in level.corners([p[0], p[1], p[2]]).into_iter().enumerate() {
                    r[l * 8 + k] = l as u32 * t + i;
                    w[l * 8 + k] = wk;
                }
            }
        });
    (rows, weights)
}

/// The tensor-op twin of [`hash_encode`]: `index_select` of the `M·L·8` corner rows of `table`
/// `(L·T, F)`, weighted and summed per level: `(M, L·F)`; its table gradient is Candle's
/// `index_add` scatter. Corner rows and weights are computed from `points` `(M, 3)` on the
/// host; when autograd tracks the points, the weights are tensor ops on them instead (the
/// same values; `hash_point_gradient::tracked_corner_weights`), so the gradient reaches them.
pub(crate) fn hash_encode_generic(
    points: &Tensor,
    table: &Tensor,
    params: &HashGridParams,
) -> candle_core::Result<Tensor> {
    check_shapes(points, table, params)?;
    let m = points.dim(0)?;
    let p = points
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let (rows, weights) = corner_rows(&p, params);
    let n = rows.len();
    let rows = Tensor::from_vec(rows, n, table.device())?;
    let weights = match points.track_op() {
        true => hash_point_gradient::tracked_corner_weights(points, &p, params)?,
        false => Tensor::from_vec(weights, (n, 1), table.device())?,
    }
    .to_dtype(table.dtype())?;
    let (l, f) = (params.n_levels, params.n_features);
    table
        .index_select(&rows, 0)?
        .broadcast_mul(&weights)?
        .reshape((m, l, 8, f))?
        .sum(2)?
        .reshape((m, l * f))
}

/// The fused encoding on host values: `(M, L·F)` of `points` `(M, 3)` (in [0, 1]³) with
/// `table` `(L·T, F)`, what [`hash_encode`] computes on the CPU.
pub fn encode_values(params: &HashGridParams, table: &[f32], points: &[f32]) -> Vec<f32> {
    let (levels, f) = (params.levels(), params.n_features);
    let width = params.output_dim();
    let mut out = vec![0f32; points.len() / 3 * width];
    out.par_chunks_mut(POINTS_PER_TASK * width)
        .zip(points.par_chunks(POINTS_PER_TASK * 3))
        .for_each(|(out, pts)| hash_block::encode_points(&levels, table, pts, out, f));
    out
}

struct HashEncode {
    params: HashGridParams,
    sink: Option<Arc<TableGradient>>,
}

impl CpuKernel<2> for HashEncode {
    const NAME: &'static str = "hash-encode";

    fn cpu_forward(&self, inputs: [CpuInput; 2]) -> KernelOutput {
        let [points, table] = CpuInput::all_f32(&inputs, Self::NAME)?;
        let out = encode_values(&self.params, table, points);
        Ok((
            out,
            Shape::from((points.len() / 3, self.params.output_dim())),
        ))
    }

    fn gradients(&self, [points, table]: [&Tensor; 2], grad: &Tensor) -> KernelGradients<2> {
        let p = &self.params;
        let (levels, t, f) = (p.levels(), p.table_size(), p.n_features);
        let [pts, g] = host_values([points, grad])?;
        let dpoints = match points.track_op() {
            true => Some(self.point_gradient(points, table, &pts, &g)?),
            false => None,
        };
        if let Some(sink) = &self.sink {
            sink.add(p, &pts, &g);
            return Ok([dpoints, None]);
        }
        let mut dtable = vec![0f32; p.n_rows() * f];
        // One task per level: each writes only its own slice of the table gradient.
        dtable
            .par_chunks_mut(t * f)
            .zip(levels.par_iter())
            .enumerate()
            .for_each(|(l, (d, level))| {
                let mut touched = vec![0u64; t.div_ceil(64)];
                hash_block::scatter_points((level, l), d, &mut touched, &pts, &g, f)
            });
        let dtable = Tensor::from_vec(dtable, table.shape(), table.device())?;
        Ok([dpoints, Some(dtable)])
    }
}

impl HashEncode {
    /// The gradient `(M, 3)` of `points` (`pts` their values) from the output gradient `g`
    /// ([`hash_point_gradient::point_gradients`]), reading `table` in place.
    fn point_gradient(
        &self,
        points: &Tensor,
        table: &Tensor,
        pts: &[f32],
        g: &[f32],
    ) -> candle_core::Result<Tensor> {
        let table = table.contiguous()?;
        let (storage, layout) = table.storage_and_layout();
        let candle_core::Storage::Cpu(cpu) = &*storage else {
            candle_core::bail!("hash-encode: the table must be on the CPU");
        };
        let values = nerf_kernels::storage::contiguous_f32(cpu, layout, "hash-encode")?;
        let p = &self.params;
        let d = hash_point_gradient::point_gradients(&p.levels(), values, pts, g, p.n_features);
        Tensor::from_vec(d, points.shape(), points.device())
    }
}

#[cfg(test)]
/// The rows of `table` (`L·T` of them) that `points` `(M, 3)` touch (any corner weight, even
/// 0): sorted, without repeats. What the sparse Adam updates after a step over these points.
pub(crate) fn touched_rows(
    points: &Tensor,
    params: &HashGridParams,
) -> candle_core::Result<Vec<u32>> {
    let p = points
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let mut seen = vec![false; params.n_rows()];
    for r in corner_rows(&p, params).0 {
        seen[r as usize] = true;
    }
    Ok((0..params.n_rows() as u32)
        .filter(|&r| seen[r as usize])
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoding_f64::hash_encoding_f64;
    use candle_core::{Device, Var};
    use nerf_kernels::test_support::{gradient_values, uniform_values, weighted_sum_gradients};
    use nerf_kernels::{with_kernel_choice, KernelChoice};

    fn params(log2_t: u32) -> HashGridParams {
        HashGridParams {
            n_levels: 4,
            n_features: 2,
            log2_table_size: log2_t,
            base_resolution: 2.0,
            max_resolution: 40.0,
        }
    }

    fn inputs(p: &HashGridParams, m: usize) -> (Tensor, Var) {
        let dev = Device::Cpu;
        let mut pts = uniform_values(m * 3, 1, 0.0f32, 1.0);
        pts[0..3].copy_from_slice(&[0.0, 1.0, 0.5]); // the box's faces
        let points = Tensor::from_vec(pts, (m, 3), &dev).unwrap();
        let table = uniform_values(p.n_rows() * p.n_features, 2, -1.0f32, 1.0);
        let table =
            Var::from_tensor(&Tensor::from_vec(table, (p.n_rows(), p.n_features), &dev).unwrap())
                .unwrap();
        (points, table)
    }

    /// The encoding of every point in f64 ([`hash_encoding_f64`]).
    fn reference(points: &[f32], table: &[f32], p: &HashGridParams) -> Vec<f64> {
        points
            .chunks(3)
            .flat_map(|q| hash_encoding_f64([q[0] as f64, q[1] as f64, q[2] as f64], table, p))
            .collect()
    }

    #[test]
    fn corners_are_the_cells_corners_by_index() {
        for log2_t in [6, 10] {
            for level in params(log2_t).levels() {
                let n = level.resolution;
                for (j, q) in uniform_values(3 * 50, 7, -0.1f32, 1.1)
                    .chunks(3)
                    .enumerate()
                {
                    let q = [q[0], q[1], q[2]];
                    let corners = level.corners(q);
                    let x = q.map(|v| v.clamp(0.0, 1.0) as f64 * n as f64);
                    let cell = x.map(|v| (v.floor() as u32).min(n - 1));
                    for (k, (row, w)) in corners.into_iter().enumerate() {
                        let bit = |a: usize| (k >> a & 1) as u32;
                        let c = [cell[0] + bit(0), cell[1] + bit(1), cell[2] + bit(2)];
                        assert_eq!(row, level.index(c), "point {j} corner {k}");
                        let want: f64 = (0..3)
                            .map(|a| {
                                let frac = x[a] - cell[a] as f64;
                                if bit(a) == 1 {
                                    frac
                                } else {
                                    1.0 - frac
                                }
                            })
                            .product();
                        assert!((w as f64 - want).abs() < 1e-5, "point {j} corner {k}");
                    }
                }
            }
        }
    }

    #[test]
    fn levels_follow_the_definition() {
        let p = params(10);
        let levels = p.levels();
        let res: Vec<u32> = levels.iter().map(|l| l.resolution).collect();
        // b = (40/2)^(1/3) = 2.714: 2, 5.43, 14.74, 40.
        assert_eq!(res, vec![2, 5, 14, 40]);
        // (N+1)³ against T = 1024: 27, 216 dense; 3375, 68921 hashed.
        let dense: Vec<bool> = levels.iter().map(|l| l.dense).collect();
        assert_eq!(dense, vec![true, true, false, false]);
        assert!(HashGridParams {
            log2_table_size: 2,
            ..p
        }
        .validate()
        .is_err());
        assert!(HashGridParams {
            max_resolution: 1.0,
            ..p
        }
        .validate()
        .is_err());
    }

    #[test]
    fn encoding_matches_a_float64_recomputation() {
        for log2_t in [6, 10, 14] {
            let p = params(log2_t);
            let (points, table) = inputs(&p, 300);
            let want = reference(
                &points.flatten_all().unwrap().to_vec1().unwrap(),
                &table.flatten_all().unwrap().to_vec1().unwrap(),
                &p,
            );
            for choice in [KernelChoice::Fused, KernelChoice::Generic] {
                let got = with_kernel_choice(choice, || hash_encode(&points, &table, &p, None))
                    .unwrap()
                    .flatten_all()
                    .unwrap()
                    .to_vec1::<f32>()
                    .unwrap();
                let err = got
                    .iter()
                    .zip(&want)
                    .map(|(g, w)| (*g as f64 - w).abs())
                    .fold(0.0, f64::max);
                assert!(err < 1e-5, "{choice:?} log2_T {log2_t}: max error {err}");
            }
        }
    }

    #[test]
    fn table_gradient_matches_finite_differences() {
        let p = params(6); // small: many hash collisions
        let (points, table) = inputs(&p, 40);
        let dev = Device::Cpu;
        let proj =
            Tensor::from_vec(uniform_values(40 * 8, 3, -1.0f32, 1.0), (40, 8), &dev).unwrap();
        let loss = |t: &Tensor| -> f64 {
            let t64 = t.to_dtype(DType::F64).unwrap();
            let enc = hash_encode_generic(&points, &t64, &p).unwrap();
            (enc * proj.to_dtype(DType::F64).unwrap())
                .unwrap()
                .sum_all()
                .unwrap()
                .to_scalar::<f64>()
                .unwrap()
        };
        let enc = hash_encode(&points, &table, &p, None).unwrap();
        let g = gradient_values(&weighted_sum_gradients(&enc, &proj), &table);
        let base: Vec<f32> = table.flatten_all().unwrap().to_vec1().unwrap();
        let eps = 1e-3f32;
        for i in (0..base.len()).step_by(7) {
            let shifted = |d: f32| {
                let mut v = base.clone();
                v[i] += d;
                Tensor::from_vec(v, table.shape(), &dev).unwrap()
            };
            let fd = (loss(&shifted(eps)) - loss(&shifted(-eps))) / (2.0 * eps as f64);
            assert!(
                (fd - g[i] as f64).abs() < 1e-3,
                "row value {i}: fd {fd}, grad {}",
                g[i]
            );
        }
    }

    #[test]
    fn fused_and_generic_agree_forward_and_backward() {
        let p = params(8);
        let (points, table) = inputs(&p, 500);
        let dev = Device::Cpu;
        let proj =
            Tensor::from_vec(uniform_values(500 * 8, 4, -1.0f32, 1.0), (500, 8), &dev).unwrap();
        let run = |choice| {
            with_kernel_choice(choice, || {
                let enc = hash_encode(&points, &table, &p, None).unwrap();
                let grads = weighted_sum_gradients(&enc, &proj);
                (
                    enc.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                    gradient_values(&grads, &table),
                )
            })
        };
        let (f_out, f_grad) = run(KernelChoice::Fused);
        let (g_out, g_grad) = run(KernelChoice::Generic);
        let max_diff = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max)
        };
        assert!(max_diff(&f_out, &g_out) < 1e-6);
        assert!(max_diff(&f_grad, &g_grad) < 1e-5);
        // Rows no point touches get no gradient, and touched_rows names exactly the others.
        let touched = touched_rows(&points, &p).unwrap();
        let mut is_touched = vec![false; p.n_rows()];
        touched.iter().for_each(|&r| is_touched[r as usize] = true);
        for (r, g) in f_grad.chunks(2).enumerate() {
            if !is_touched[r] {
                assert_eq!(g, [0.0, 0.0], "row {r}");
            }
        }
        assert!(touched.len() < p.n_rows());
    }

    #[test]
    fn bad_shapes_are_errors() {
        let p = params(6);
        let (points, table) = inputs(&p, 4);
        assert!(hash_encode(&points.narrow(1, 0, 2).unwrap(), &table, &p, None).is_err());
        assert!(hash_encode(&points, &table.narrow(0, 0, 10).unwrap(), &p, None).is_err());
    }

    #[test]
    fn gradient_sink_holds_the_dense_gradient_on_the_touched_rows() {
        let p = params(6);
        let (points, table) = inputs(&p, 150);
        let weight = Tensor::randn(0f32, 1.0, (150, p.output_dim()), &Device::Cpu).unwrap();
        let encoded = hash_encode(&points, &table, &p, None).unwrap();
        let dense = gradient_values(&weighted_sum_gradients(&encoded, &weight), &table);
        let sink = Arc::new(TableGradient::new(&p));
        // Two backward passes accumulate, as two chunks of one step do.
        for half in [0, 75] {
            let pts = points.narrow(0, half, 75).unwrap();
            let w = weight.narrow(0, half, 75).unwrap();
            let encoded = hash_encode(&pts, &table, &p, Some(&sink)).unwrap();
            let grads = weighted_sum_gradients(&encoded, &w);
            assert!(
                grads.get(&table).is_none(),
                "the table gradient went to autograd"
            );
        }
        let mut rows = sink.take(&p, |rows, values| {
            for (r, (a, b)) in values.chunks(2).zip(dense.chunks(2)).enumerate() {
                assert!(
                    (a[0] - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5,
                    "row {r}"
                );
            }
            rows.to_vec()
        });
        rows.sort_unstable();
        assert_eq!(rows, touched_rows(&points, &p).unwrap());
        // Taken means cleared.
        sink.take(&p, |rows, values| {
            assert!(rows.is_empty() && values.iter().all(|&v| v == 0.0));
        });
    }
}
