//! The real spherical harmonics of degrees 0–3 that encode a ray's direction for the
//! hash-grid field's colour MLP (instant-ngp's order and constants): per direction on the host,
//! and as tensor ops when the directions are trained.

use anyhow::Result;
use candle_core::{DType, Tensor};

/// Values of the degree-4 spherical-harmonics basis (`4²`).
pub const SH_DIM: usize = 16;

/// The real spherical harmonics of degrees 0–3 (16 values, instant-ngp's order and constants)
/// of a unit direction `d`.
pub fn sh_basis(d: [f32; 3]) -> [f32; SH_DIM] {
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let (xy, yz, xz) = (x * y, y * z, x * z);
    [
        0.282_094_8,
        -0.488_602_52 * y,
        0.488_602_52 * z,
        -0.488_602_52 * x,
        1.092_548_5 * xy,
        -1.092_548_5 * yz,
        0.946_174_7 * zz - 0.315_391_57,
        -1.092_548_5 * xz,
        0.546_274_24 * (xx - yy),
        0.590_043_6 * y * (-3.0 * xx + yy),
        2.890_611_4 * xy * z,
        0.457_045_8 * y * (1.0 - 5.0 * zz),
        0.373_176_34 * z * (5.0 * zz - 3.0),
        0.457_045_8 * x * (1.0 - 5.0 * zz),
        1.445_305_7 * z * (xx - yy),
        0.590_043_6 * x * (-xx + 3.0 * yy),
    ]
}

/// [`sh_basis`] of each unit direction in `directions` (`(N, 3)` row-major host values):
/// `(N, 16)` row-major.
pub fn sh_basis_values(directions: &[f32]) -> Vec<f32> {
    directions
        .chunks_exact(3)
        .flat_map(|v| sh_basis([v[0], v[1], v[2]]))
        .collect()
}

/// [`sh_basis`] of every row of `directions` `(N, 3)`: `(N, 16)`, in `directions`' dtype;
/// as tensor ops ([`sh_encode_tensor_ops`]) when autograd tracks the directions (rays being
/// trained, camera refinement), so that the gradient reaches them.
pub fn sh_encode(directions: &Tensor) -> Result<Tensor> {
    if directions.track_op() {
        return sh_encode_tensor_ops(directions);
    }
    let n = directions.dim(0)?;
    let d = directions
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()?;
    let sh = sh_basis_values(&d);
    Ok(Tensor::from_vec(sh, (n, SH_DIM), directions.device())?.to_dtype(directions.dtype())?)
}

/// [`sh_basis`] of every row of `directions` `(N, 3)` as Candle ops (differentiable): `(N, 16)`.
pub fn sh_encode_tensor_ops(directions: &Tensor) -> Result<Tensor> {
    let d = directions;
    let (x, y, z) = (d.narrow(1, 0, 1)?, d.narrow(1, 1, 1)?, d.narrow(1, 2, 1)?);
    let (xx, yy, zz) = (x.sqr()?, y.sqr()?, z.sqr()?);
    let (xy, yz, xz) = ((&x * &y)?, (&y * &z)?, (&x * &z)?);
    let one_minus_5zz = zz.affine(-5.0, 1.0)?;
    let columns = [
        x.ones_like()?.affine(0.282_094_8, 0.0)?,
        y.affine(-0.488_602_52, 0.0)?,
        z.affine(0.488_602_52, 0.0)?,
        x.affine(-0.488_602_52, 0.0)?,
        xy.affine(1.092_548_5, 0.0)?,
        yz.affine(-1.092_548_5, 0.0)?,
        zz.affine(0.946_174_7, -0.315_391_57)?,
        xz.affine(-1.092_548_5, 0.0)?,
        (&xx - &yy)?.affine(0.546_274_24, 0.0)?,
        (&y * (&yy - xx.affine(3.0, 0.0)?)?)?.affine(0.590_043_6, 0.0)?,
        (&xy * &z)?.affine(2.890_611_4, 0.0)?,
        (&y * &one_minus_5zz)?.affine(0.457_045_8, 0.0)?,
        (&z * zz.affine(5.0, -3.0)?)?.affine(0.373_176_34, 0.0)?,
        (&x * &one_minus_5zz)?.affine(0.457_045_8, 0.0)?,
        (&z * (&xx - &yy)?)?.affine(1.445_305_7, 0.0)?,
        (&x * (yy.affine(3.0, 0.0)? - &xx)?)?.affine(0.590_043_6, 0.0)?,
    ];
    Ok(Tensor::cat(&columns, 1)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};

    #[test]
    fn sh_basis_matches_hand_values() {
        // +z: only the zonal terms (m = 0) are non-zero: Y00, Y10 = √(3/4π), Y20, Y30.
        let z = sh_basis([0.0, 0.0, 1.0]);
        let pi = std::f32::consts::PI;
        assert!((z[0] - 0.5 / pi.sqrt()).abs() < 1e-6);
        assert!((z[2] - (3.0 / (4.0 * pi)).sqrt()).abs() < 1e-6);
        assert!((z[6] - 0.25 * (5.0 / pi).sqrt() * 2.0).abs() < 1e-6); // (3z²−1)·¼√(5/π)
        assert!((z[12] - 0.25 * (7.0 / pi).sqrt() * 2.0).abs() < 1e-6); // (5z³−3z)·¼√(7/π)
        for k in [1, 3, 4, 5, 7, 8, 9, 10, 11, 13, 14, 15] {
            assert_eq!(z[k], 0.0, "term {k}");
        }
        // +x: Y1,1 = −√(3/4π)·x in this sign convention; Y2,2 = ¼√(15/π)·(x²−y²); Y2,0 = −¼√(5/π).
        let x = sh_basis([1.0, 0.0, 0.0]);
        assert!((x[3] + (3.0 / (4.0 * pi)).sqrt()).abs() < 1e-6);
        assert!((x[8] - 0.25 * (15.0 / pi).sqrt()).abs() < 1e-6);
        assert!((x[6] + 0.25 * (5.0 / pi).sqrt()).abs() < 1e-6);
        // The squares of each degree's values sum to (2l+1)/4π for any unit direction.
        let v = sh_basis([0.48, -0.6, 0.64]);
        for (l, range) in [(0usize, 0..1), (1, 1..4), (2, 4..9), (3, 9..16)] {
            let s: f32 = v[range].iter().map(|a| a * a).sum();
            assert!(
                (s - (2 * l + 1) as f32 / (4.0 * pi)).abs() < 1e-5,
                "degree {l}"
            );
        }
    }

    #[test]
    fn sh_tensor_ops_give_the_basis_and_its_derivatives() {
        let dirs = [[0.48f32, -0.6, 0.64], [0.0, 0.0, 1.0], [-0.36, 0.48, -0.8]];
        let var = Var::new(&dirs, &Device::Cpu).unwrap();
        let sh = sh_encode(var.as_tensor()).unwrap();
        let got = sh.to_vec2::<f32>().unwrap();
        for (d, row) in dirs.iter().zip(&got) {
            let want = sh_basis(*d);
            for k in 0..SH_DIM {
                assert!((row[k] - want[k]).abs() < 1e-6, "{d:?} term {k}");
            }
        }
        // The gradient of a weighted sum against central differences of sh_basis in f64.
        let w: Vec<f32> = (0..3 * SH_DIM).map(|i| (i as f32 * 0.9).sin()).collect();
        let wt = Tensor::from_vec(w.clone(), (3, SH_DIM), &Device::Cpu).unwrap();
        let g = (sh * wt).unwrap().sum_all().unwrap().backward().unwrap();
        let g = g.get(var.as_tensor()).unwrap().to_vec2::<f32>().unwrap();
        for (j, d) in dirs.iter().enumerate() {
            for a in 0..3 {
                let f = |e: f32| -> f64 {
                    let mut q = *d;
                    q[a] += e;
                    let b = sh_basis(q);
                    (0..SH_DIM)
                        .map(|k| b[k] as f64 * w[j * SH_DIM + k] as f64)
                        .sum()
                };
                let fd = (f(1e-3) - f(-1e-3)) / 2e-3;
                assert!(
                    (g[j][a] as f64 - fd).abs() < 1e-3,
                    "{d:?} axis {a}: {} vs {fd}",
                    g[j][a]
                );
            }
        }
    }
}
