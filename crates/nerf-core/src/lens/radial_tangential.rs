//! Radial and tangential distortion (Brown–Conrady): COLMAP's `SIMPLE_RADIAL`, `RADIAL`,
//! `OPENCV` and `FULL_OPENCV`, and nerfstudio's `OPENCV`.
//!
//! With `r² = x² + y²`,
//! `radial = (1 + a₁r² + a₂r⁴ + a₃r⁶ + a₄r⁸) / (1 + b₁r² + b₂r⁴ + b₃r⁶)`,
//! `x_d = x·radial + 2p₁xy + p₂(r² + 2x²)`, `y_d = y·radial + 2p₂xy + p₁(r² + 2y²)`.
//! Undistortion is Newton's method with the analytic Jacobian (COLMAP's
//! `IterativeUndistortion`, nerfstudio's `radial_and_tangential_undistort`).

use glam::{DVec2, DVec3};

use super::lens_model::{ColmapCameraModel, LensModel, MAX_NEWTON_STEPS, RESIDUAL_TOLERANCE};
use super::LensDistortion;
use crate::term::short_number;

/// Radial (rational polynomial in `r²`) and tangential distortion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadialTangential {
    /// Numerator coefficients `[a₁, a₂, a₃, a₄]` of `r², r⁴, r⁶, r⁸` (COLMAP's k1, k2, k3;
    /// nerfstudio's `OPENCV` also uses a₄ = k4).
    pub numerator: [f64; 4],
    /// Denominator coefficients `[b₁, b₂, b₃]` of `r², r⁴, r⁶` (COLMAP `FULL_OPENCV`'s k4,
    /// k5, k6; zero elsewhere).
    pub denominator: [f64; 3],
    /// Tangential coefficients `[p₁, p₂]`.
    pub tangential: [f64; 2],
}

/// `distort(p)` and its 2×2 Jacobian `[[∂x_d/∂x, ∂x_d/∂y], [∂y_d/∂x, ∂y_d/∂y]]`.
pub(crate) struct DistortionWithJacobian {
    pub(crate) value: DVec2,
    pub(crate) jacobian: [[f64; 2]; 2],
}

impl RadialTangential {
    /// `distort(p)` and its analytic Jacobian.
    pub(crate) fn with_jacobian(&self, p: DVec2) -> DistortionWithJacobian {
        let [a1, a2, a3, a4] = self.numerator;
        let [b1, b2, b3] = self.denominator;
        let [p1, p2] = self.tangential;
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        // Horner in r²: N = 1 + a₁r² + a₂r⁴ + a₃r⁶ + a₄r⁸, D = 1 + b₁r² + b₂r⁴ + b₃r⁶.
        let n = 1.0 + r2 * (a1 + r2 * (a2 + r2 * (a3 + r2 * a4)));
        let d = 1.0 + r2 * (b1 + r2 * (b2 + r2 * b3));
        let dn = a1 + r2 * (2.0 * a2 + r2 * (3.0 * a3 + r2 * 4.0 * a4));
        let dd = b1 + r2 * (2.0 * b2 + r2 * 3.0 * b3);
        let radial = n / d;
        // d(radial)/d(r²); ∂r²/∂x = 2x, ∂r²/∂y = 2y.
        let radial_r2 = (dn * d - n * dd) / (d * d);
        let value = DVec2::new(
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + 2.0 * p2 * x * y + p1 * (r2 + 2.0 * y * y),
        );
        let jacobian = [
            [
                radial + 2.0 * x * x * radial_r2 + 2.0 * p1 * y + 6.0 * p2 * x,
                2.0 * x * y * radial_r2 + 2.0 * p1 * x + 2.0 * p2 * y,
            ],
            [
                2.0 * x * y * radial_r2 + 2.0 * p2 * y + 2.0 * p1 * x,
                radial + 2.0 * y * y * radial_r2 + 2.0 * p2 * x + 6.0 * p1 * y,
            ],
        ];
        DistortionWithJacobian { value, jacobian }
    }

    /// Newton's method on `distort(p) = target`, from `p = target`, with the analytic
    /// Jacobian; returns the iterate with the smallest residual.
    fn solve(&self, target: DVec2) -> DVec2 {
        let mut p = target;
        let mut best = (f64::INFINITY, p);
        for _ in 0..MAX_NEWTON_STEPS {
            let DistortionWithJacobian { value, jacobian } = self.with_jacobian(p);
            let residual = value - target;
            let size = residual.length();
            if !size.is_finite() {
                break;
            }
            if size < best.0 {
                best = (size, p);
            }
            if size <= RESIDUAL_TOLERANCE {
                break;
            }
            let [[j00, j01], [j10, j11]] = jacobian;
            let det = j00 * j11 - j01 * j10;
            if det.abs() < 1e-300 || !det.is_finite() {
                break;
            }
            // p ← p − J⁻¹ · residual.
            let step = DVec2::new(
                (j11 * residual.x - j01 * residual.y) / det,
                (-j10 * residual.x + j00 * residual.y) / det,
            );
            p -= step;
            if step.length() <= 1e-17 * (1.0 + p.length()) {
                break;
            }
        }
        best.1
    }
}

impl LensModel for RadialTangential {
    fn distort(&self, p: DVec2) -> DVec2 {
        self.with_jacobian(p).value
    }

    fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        Some(self.solve(distorted))
    }

    fn undistorted_direction(&self, distorted: DVec2) -> DVec3 {
        self.solve(distorted).extend(1.0).normalize()
    }

    fn check_invertible_at(&self, d: DVec2, tolerance: f64) -> Result<(), String> {
        let p = self.solve(d);
        let DistortionWithJacobian { value, jacobian } = self.with_jacobian(p);
        let residual = (value - d).length();
        if residual.is_nan() || residual > tolerance {
            return Err(format!(
                "undistorting ({:.4}, {:.4}) does not converge (residual {})",
                d.x,
                d.y,
                short_number(residual)
            ));
        }
        let [[j00, j01], [j10, j11]] = jacobian;
        let det = j00 * j11 - j01 * j10;
        if det.is_nan() || det <= 0.0 {
            return Err(format!(
                "the distortion folds over at ({:.4}, {:.4}) (its Jacobian's \
                 determinant is not positive there)",
                d.x, d.y
            ));
        }
        Ok(())
    }

    fn coefficients(&self) -> Vec<f64> {
        self.numerator
            .iter()
            .chain(&self.denominator)
            .chain(&self.tangential)
            .copied()
            .collect()
    }
}

/// COLMAP's radial–tangential models; `p` holds the parameters after `cx, cy`.
pub(crate) const COLMAP_MODELS: &[ColmapCameraModel] = &[
    ColmapCameraModel {
        id: 2,
        name: "SIMPLE_RADIAL",
        parameters: &["f", "cx", "cy", "k"],
        lens: |p| LensDistortion::polynomial([p[0], 0.0, 0.0, 0.0], [0.0, 0.0]),
    },
    ColmapCameraModel {
        id: 3,
        name: "RADIAL",
        parameters: &["f", "cx", "cy", "k1", "k2"],
        lens: |p| LensDistortion::polynomial([p[0], p[1], 0.0, 0.0], [0.0, 0.0]),
    },
    ColmapCameraModel {
        id: 4,
        name: "OPENCV",
        parameters: &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"],
        lens: |p| LensDistortion::polynomial([p[0], p[1], 0.0, 0.0], [p[2], p[3]]),
    },
    ColmapCameraModel {
        id: 6,
        name: "FULL_OPENCV",
        parameters: &[
            "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
        ],
        lens: |p| {
            LensDistortion::RadialTangential(RadialTangential {
                numerator: [p[0], p[1], p[4], 0.0],
                denominator: [p[5], p[6], p[7]],
                tangential: [p[2], p[3]],
            })
        },
    },
];
