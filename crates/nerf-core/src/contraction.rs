//! Scene contraction for unbounded captures: the L∞ form that mip-NeRF 360 introduced (with
//! the L2 norm) and nerfacto uses with hash grids (`SceneContraction(order=inf)`):
//!
//! `contract(x) = x` where `‖x‖∞ ≤ 1`, else `(2 − 1/‖x‖∞) · x / ‖x‖∞`,
//!
//! which maps all of space into the cube `[-2, 2]³`: the unit cube unchanged, everything beyond
//! it squeezed into the shell between the cubes of half-size 1 and 2 (a point at distance `r`
//! lands at `2 − 1/r`). The map is continuous (both forms give `x` on the unit cube's faces)
//! and invertible: [`Contraction::uncontract`]. Written by hand (a few lines of arithmetic);
//! the tensor form [`Contraction::contract_tensor`] is made of Candle ops.

use anyhow::Result;
use candle_core::Tensor;

/// How world points map into the space a field's grid covers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Contraction {
    /// Identity: the grid covers a box of the world (bounded scenes).
    #[default]
    None,
    /// The L∞ contraction into `[-2, 2]³` (unbounded scenes).
    LInf,
}

/// Largest L∞ norm a contracted point is given when mapped back ([`Contraction::uncontract`]):
/// the cube of half-size 2 is infinitely far away, so points on it are brought just inside
/// (at world distance `1 / (2 − UNCONTRACT_MAX) = 10⁴`).
pub(crate) const UNCONTRACT_MAX: f64 = 2.0 - 1e-4;

/// `none` or `linf`, as a config writes it (`implicit_function.contraction`).
impl<'de> serde::Deserialize<'de> for Contraction {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        crate::key_checks::deserialize_name(d, &[("none", Self::None), ("linf", Self::LInf)])
    }
}

impl Contraction {
    /// The contracted point of world point `p`.
    pub fn contract(self, p: [f64; 3]) -> [f64; 3] {
        match self {
            Self::None => p,
            Self::LInf => linf_contract(p),
        }
    }

    /// [`Contraction::contract`] in f32 (the occupancy grid's per-sample test).
    #[inline]
    pub fn contract_f32(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            Self::None => p,
            Self::LInf => linf_contract(p),
        }
    }

    /// The world point whose contraction is `q` (`‖q‖∞` clamped to `UNCONTRACT_MAX`): for
    /// `1 < ‖q‖∞ = m < 2`, the point along `q` at L∞ distance `1 / (2 − m)`.
    pub fn uncontract(self, q: [f64; 3]) -> [f64; 3] {
        match self {
            Self::None => q,
            Self::LInf => {
                let norm = linf_norm(q);
                if norm <= 1.0 {
                    q
                } else {
                    let m = norm.min(UNCONTRACT_MAX);
                    let world_norm = 1.0 / (2.0 - m);
                    q.map(|v| v / norm * world_norm)
                }
            }
        }
    }

    /// Contracted points `(M, 3)` of world `points` `(M, 3)` (any float dtype).
    ///
    /// With `n = max(‖x‖∞, 1)` the contraction is `x · (2n − 1) / n²` in both regions (inside
    /// the unit cube `n = 1` and the factor is 1), so no branch is needed. Differentiable in
    /// `points` (Candle ops), though the fields that use it need no gradient there.
    pub fn contract_tensor(self, points: &Tensor) -> Result<Tensor> {
        Ok(match self {
            Self::None => points.clone(),
            Self::LInf => {
                let n = points.abs()?.max_keepdim(1)?.maximum(1.0)?;
                let scale = ((n.affine(2.0, -1.0)? / n.sqr()?)?).contiguous()?;
                points.broadcast_mul(&scale)?
            }
        })
    }
}

/// The float widths the contraction is computed in: f64 for geometry, f32 for the occupancy
/// grid's per-sample test. One formula serves both ([`linf_contract`]), each in its own width.
trait Real:
    Copy
    + PartialOrd
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
{
    const ZERO: Self;
    const ONE: Self;
    const TWO: Self;
    fn abs(self) -> Self;
    fn max(self, other: Self) -> Self;
}

macro_rules! real {
    ($($t:ty),*) => {$(
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const TWO: Self = 2.0;
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
        }
    )*};
}
real!(f32, f64);

/// `‖p‖∞`.
#[inline(always)]
fn linf_norm<T: Real>(p: [T; 3]) -> T {
    p.iter().fold(T::ZERO, |m, v| m.max(v.abs()))
}

/// The L∞ contraction of `p`: `p` where `‖p‖∞ ≤ 1`, else `(2 − 1/‖p‖∞) · p / ‖p‖∞`.
#[inline(always)]
fn linf_contract<T: Real>(p: [T; 3]) -> [T; 3] {
    let norm = linf_norm(p);
    if norm <= T::ONE {
        p
    } else {
        let scale = (T::TWO - T::ONE / norm) / norm;
        p.map(|v| v * scale)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    #[test]
    fn inside_the_unit_cube_nothing_moves() {
        for p in [
            [0.0, 0.0, 0.0],
            [0.5, -1.0, 0.25],
            [1.0, 1.0, 1.0],
            [-0.9, 0.3, 0.99],
        ] {
            assert_eq!(Contraction::LInf.contract(p), p);
            assert_eq!(Contraction::None.contract(p), p);
        }
    }

    #[test]
    fn analytic_values_outside() {
        // ‖x‖∞ = 2 → the point lands at L∞ norm 2 − 1/2 = 1.5, along x.
        let q = Contraction::LInf.contract([2.0, -1.0, 0.5]);
        let want = [1.5, -0.75, 0.375];
        for k in 0..3 {
            assert!((q[k] - want[k]).abs() < 1e-15, "{q:?}");
        }
        // Along an axis at distance r: 2 − 1/r.
        for r in [1.5, 3.0, 10.0, 1e3, 1e6] {
            let q = Contraction::LInf.contract([0.0, 0.0, -r]);
            assert!((q[2] + (2.0 - 1.0 / r)).abs() < 1e-12, "{r}: {q:?}");
            assert_eq!(q[0], 0.0);
        }
        // Everything lands in [-2, 2]³, strictly inside.
        let far = Contraction::LInf.contract([1e12, -3e11, 7.0]);
        assert!(far.iter().all(|v| v.abs() < 2.0), "{far:?}");
    }

    #[test]
    fn continuous_across_the_unit_cube() {
        // Just inside and just outside a face (and an edge, and a corner) agree to O(ε).
        for dir in [[1.0, 0.3, -0.2], [1.0, 1.0, 0.0], [-1.0, 1.0, -1.0]] {
            for eps in [1e-3, 1e-6, 1e-9] {
                let inside = Contraction::LInf.contract(dir.map(|v: f64| v * (1.0 - eps)));
                let outside = Contraction::LInf.contract(dir.map(|v: f64| v * (1.0 + eps)));
                for k in 0..3 {
                    assert!((inside[k] - outside[k]).abs() < 4.0 * eps, "{dir:?} {eps}");
                }
            }
        }
    }

    #[test]
    fn uncontract_inverts_contract() {
        for p in [
            [0.2, -0.4, 0.9],
            [3.0, 1.0, -2.0],
            [-50.0, 20.0, 49.0],
            [0.0, 0.0, 900.0],
        ] {
            let back = Contraction::LInf.uncontract(Contraction::LInf.contract(p));
            for k in 0..3 {
                assert!(
                    (back[k] - p[k]).abs() < 1e-9 * p[k].abs().max(1.0),
                    "{p:?}: {back:?}"
                );
            }
        }
        // The outer cube itself comes back finite.
        let edge = Contraction::LInf.uncontract([2.0, 0.0, 0.0]);
        assert!((edge[0] - 1.0 / (2.0 - UNCONTRACT_MAX)).abs() < 1e-6);
    }

    #[test]
    fn tensor_form_matches_the_f64_recomputation() {
        let points: Vec<[f64; 3]> = vec![
            [0.0, 0.0, 0.0],
            [0.7, -0.2, 1.0],
            [1.0 + 1e-4, 0.0, 0.0],
            [2.0, -1.0, 0.5],
            [-30.0, 4.0, 12.0],
            [600.0, -900.0, 5.0],
        ];
        let flat: Vec<f32> = points.iter().flatten().map(|&v| v as f32).collect();
        let t = Tensor::from_vec(flat, (points.len(), 3), &Device::Cpu).unwrap();
        let got = Contraction::LInf
            .contract_tensor(&t)
            .unwrap()
            .to_vec2::<f32>()
            .unwrap();
        for (p, g) in points.iter().zip(&got) {
            let want = Contraction::LInf.contract(*p);
            let f = Contraction::LInf.contract_f32(p.map(|v| v as f32));
            for k in 0..3 {
                assert!(
                    (g[k] as f64 - want[k]).abs() < 1e-6,
                    "{p:?}: {g:?} vs {want:?}"
                );
                assert!(
                    (f[k] as f64 - want[k]).abs() < 1e-6,
                    "{p:?}: {f:?} vs {want:?}"
                );
            }
        }
        // f64 in, f64 out.
        let t64 = t.to_dtype(DType::F64).unwrap();
        assert_eq!(
            Contraction::LInf.contract_tensor(&t64).unwrap().dtype(),
            DType::F64
        );
    }

    #[test]
    fn tensor_form_derivative_matches_finite_differences() {
        // d contract_k / d x_j by central differences of the f64 map, against autograd.
        let dev = Device::Cpu;
        for p in [[0.3, -0.5, 0.2], [2.5, 1.0, -0.5], [-0.4, -7.0, 3.0]] {
            for j in 0..3 {
                let x = candle_core::Var::new(&[p], &dev).unwrap();
                let y = Contraction::LInf.contract_tensor(x.as_tensor()).unwrap();
                for k in 0..3 {
                    let yk = y.narrow(1, k, 1).unwrap().sum_all().unwrap();
                    let g = yk.backward().unwrap();
                    let auto = g.get(&x).unwrap().to_vec2::<f64>().unwrap()[0][j];
                    let h = 1e-6;
                    let mut plus = p;
                    let mut minus = p;
                    plus[j] += h;
                    minus[j] -= h;
                    let fd = (Contraction::LInf.contract(plus)[k]
                        - Contraction::LInf.contract(minus)[k])
                        / (2.0 * h);
                    assert!((auto - fd).abs() < 1e-6, "{p:?} d{k}/d{j}: {auto} vs {fd}");
                }
            }
        }
    }
}
