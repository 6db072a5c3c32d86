//! Lens distortion on the normalised image plane, as COLMAP and nerfstudio model it.
//!
//! A camera-space point `(X, Y, Z)` (OpenCV axes: +x right, +y down, +z forward) lands on the
//! normalised plane at `p = (X / Z, Y / Z)`; the lens moves it to the distorted point
//! `distort(p)`, which the intrinsics then scale and shift into pixels. Undistortion inverts
//! `distort` by Newton's method (COLMAP's `IterativeUndistortion`, nerfstudio's
//! `radial_and_tangential_undistort`), to a residual of 1e-10 or better.
//!
//! Two families cover COLMAP's models `SIMPLE_RADIAL`, `RADIAL`, `OPENCV`, `FULL_OPENCV` and
//! `OPENCV_FISHEYE` (and nerfstudio's `OPENCV` and `OPENCV_FISHEYE`):
//!
//! * [`LensDistortion::RadialTangential`] (Brown–Conrady): with `r² = x² + y²`,
//!   `radial = (1 + a₁r² + a₂r⁴ + a₃r⁶ + a₄r⁸) / (1 + b₁r² + b₂r⁴ + b₃r⁶)`,
//!   `x_d = x·radial + 2p₁xy + p₂(r² + 2x²)`, `y_d = y·radial + 2p₂xy + p₁(r² + 2y²)`.
//! * [`LensDistortion::Fisheye`] (Kannala–Brandt, OpenCV's fisheye): with `θ = atan(r)`,
//!   `θ_d = θ(1 + k₁θ² + k₂θ⁴ + k₃θ⁶ + k₄θ⁸)` and `p_d = p · θ_d / r`.

use glam::{DVec2, DVec3};

use crate::term::short_number;

/// Newton stops when the residual `|distort(p) − target|` is below this (normalised units).
const RESIDUAL_TOLERANCE: f64 = 1e-14;
/// Newton gives up after this many steps, keeping the iterate with the smallest residual.
const MAX_NEWTON_STEPS: usize = 100;
/// Radii below this are treated as the optical axis (as COLMAP does with machine epsilon).
const AXIS_RADIUS: f64 = f64::EPSILON;

/// How a lens moves points on the normalised image plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LensDistortion {
    /// An ideal pinhole: `distort(p) = p`.
    None,
    /// Radial (rational polynomial in `r²`) and tangential distortion.
    RadialTangential {
        /// Numerator coefficients `[a₁, a₂, a₃, a₄]` of `r², r⁴, r⁶, r⁸` (COLMAP's k1, k2, k3;
        /// nerfstudio's `OPENCV` also uses a₄ = k4).
        numerator: [f64; 4],
        /// Denominator coefficients `[b₁, b₂, b₃]` of `r², r⁴, r⁶` (COLMAP `FULL_OPENCV`'s k4,
        /// k5, k6; zero elsewhere).
        denominator: [f64; 3],
        /// Tangential coefficients `[p₁, p₂]`.
        tangential: [f64; 2],
    },
    /// The equidistant fisheye with a polynomial in the angle `θ` from the optical axis.
    Fisheye {
        /// `[k₁, k₂, k₃, k₄]`, the coefficients of `θ², θ⁴, θ⁶, θ⁸`.
        k: [f64; 4],
    },
}

/// `distort(p)` and its 2×2 Jacobian `[[∂x_d/∂x, ∂x_d/∂y], [∂y_d/∂x, ∂y_d/∂y]]`.
struct DistortionWithJacobian {
    value: DVec2,
    jacobian: [[f64; 2]; 2],
}

impl LensDistortion {
    /// Radial and tangential distortion with a plain polynomial radial term
    /// `1 + k₁r² + k₂r⁴ + k₃r⁶ + k₄r⁸`.
    pub fn polynomial(radial: [f64; 4], tangential: [f64; 2]) -> Self {
        Self::RadialTangential {
            numerator: radial,
            denominator: [0.0; 3],
            tangential,
        }
    }

    /// Every coefficient, for finiteness checks.
    pub fn coefficients(&self) -> Vec<f64> {
        match self {
            Self::None => Vec::new(),
            Self::RadialTangential {
                numerator,
                denominator,
                tangential,
            } => numerator
                .iter()
                .chain(denominator)
                .chain(tangential)
                .copied()
                .collect(),
            Self::Fisheye { k } => k.to_vec(),
        }
    }

    /// The distorted normalised point of the undistorted normalised point `p`.
    pub(crate) fn distort(&self, p: DVec2) -> DVec2 {
        match self {
            Self::None => p,
            Self::RadialTangential { .. } => self.radial_tangential_with_jacobian(p).value,
            Self::Fisheye { k } => {
                let r = p.length();
                if r <= AXIS_RADIUS {
                    return p;
                }
                let theta = r.atan();
                p * (fisheye_theta_d(k, theta) / r)
            }
        }
    }

    /// The undistorted normalised point whose distortion is `distorted`, or `None` when it
    /// has none: a fisheye ray 90° or more from the optical axis. Where Newton cannot reach
    /// the tolerance (a fold of the distortion, far outside any calibrated field) this is the
    /// iterate with the smallest residual.
    pub(crate) fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        match self {
            Self::None => Some(distorted),
            Self::RadialTangential { .. } => Some(self.undistort_radial_tangential(distorted)),
            Self::Fisheye { .. } => {
                let direction = self.undistorted_direction(distorted);
                (direction.z > 0.0).then(|| DVec2::new(direction.x, direction.y) / direction.z)
            }
        }
    }

    /// The unit camera-space direction (OpenCV axes) of the ray imaged at the distorted
    /// normalised point `distorted`. Unlike [`Self::undistort`] this exists for fisheye rays
    /// at or beyond 90° from the axis too (`z ≤ 0`).
    pub(crate) fn undistorted_direction(&self, distorted: DVec2) -> DVec3 {
        match self {
            Self::None => distorted.extend(1.0).normalize(),
            Self::RadialTangential { .. } => self
                .undistort_radial_tangential(distorted)
                .extend(1.0)
                .normalize(),
            Self::Fisheye { k } => {
                let rho = distorted.length();
                if rho <= AXIS_RADIUS {
                    return distorted.extend(1.0).normalize();
                }
                let theta = solve_fisheye_theta(k, rho);
                let radial = distorted / rho * theta.sin();
                radial.extend(theta.cos())
            }
        }
    }

    /// Whether the lens maps one ray to each of `points` (distorted normalised points, spread
    /// over an image): at each, undistortion converges (`distort(undistort(d))` within `1e-9 ·
    /// (1 + |d|)` of `d`) and the distortion keeps its orientation there (a positive Jacobian
    /// determinant; for a fisheye, `θ_d` rising with `θ`, below 180°). Newton failing to
    /// converge is this error, never a silent fallback to the distorted point. The error says
    /// which point failed and how.
    pub(crate) fn check_invertible_at(&self, points: &[DVec2]) -> Result<(), String> {
        let tolerance = |d: DVec2| 1e-9 * (1.0 + d.length());
        for &d in points {
            match self {
                Self::None => {}
                Self::RadialTangential { .. } => {
                    let p = self.undistort_radial_tangential(d);
                    let DistortionWithJacobian { value, jacobian } =
                        self.radial_tangential_with_jacobian(p);
                    let residual = (value - d).length();
                    if residual.is_nan() || residual > tolerance(d) {
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
                }
                Self::Fisheye { k } => {
                    let rho = d.length();
                    let theta = solve_fisheye_theta(k, rho);
                    let residual = (fisheye_theta_d(k, theta) - rho).abs();
                    if residual.is_nan() || residual > tolerance(d) {
                        return Err(format!(
                            "undistorting the fisheye radius {rho:.4} does not converge \
                             (residual {})",
                            short_number(residual)
                        ));
                    }
                    let slope = fisheye_slope(k, theta);
                    if slope.is_nan() || slope <= 0.0 {
                        return Err(format!(
                            "the fisheye's θ_d stops rising at θ = {:.1}°",
                            theta.to_degrees()
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// `distort(p)` and its analytic Jacobian for the radial–tangential family (identity for
    /// the others, which never call it).
    fn radial_tangential_with_jacobian(&self, p: DVec2) -> DistortionWithJacobian {
        let Self::RadialTangential {
            numerator: [a1, a2, a3, a4],
            denominator: [b1, b2, b3],
            tangential: [p1, p2],
        } = *self
        else {
            return DistortionWithJacobian {
                value: p,
                jacobian: [[1.0, 0.0], [0.0, 1.0]],
            };
        };
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
    fn undistort_radial_tangential(&self, target: DVec2) -> DVec2 {
        let mut p = target;
        let mut best = (f64::INFINITY, p);
        for _ in 0..MAX_NEWTON_STEPS {
            let DistortionWithJacobian { value, jacobian } =
                self.radial_tangential_with_jacobian(p);
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

/// The fisheye's `θ_d = θ(1 + k₁θ² + k₂θ⁴ + k₃θ⁶ + k₄θ⁸)`.
fn fisheye_theta_d(&[k1, k2, k3, k4]: &[f64; 4], theta: f64) -> f64 {
    let t2 = theta * theta;
    theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
}

/// `dθ_d/dθ` of [`fisheye_theta_d`].
fn fisheye_slope(&[k1, k2, k3, k4]: &[f64; 4], theta: f64) -> f64 {
    let t2 = theta * theta;
    1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
}

/// The angle `θ ∈ [0, π)` with `θ_d(θ) = rho`, by Newton from `θ = rho` (1-D: the fisheye
/// distortion is purely radial); the iterate with the smallest residual.
fn solve_fisheye_theta(k: &[f64; 4], rho: f64) -> f64 {
    let mut theta = rho.min(std::f64::consts::PI * 0.999);
    let mut best = (f64::INFINITY, theta);
    for _ in 0..MAX_NEWTON_STEPS {
        let residual = fisheye_theta_d(k, theta) - rho;
        if !residual.is_finite() {
            break;
        }
        if residual.abs() < best.0 {
            best = (residual.abs(), theta);
        }
        if residual.abs() <= RESIDUAL_TOLERANCE {
            break;
        }
        let slope = fisheye_slope(k, theta);
        if slope.abs() < 1e-300 {
            break;
        }
        theta = (theta - residual / slope).clamp(0.0, std::f64::consts::PI * 0.999);
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Realistic lenses of each family.
    fn lenses() -> Vec<(&'static str, LensDistortion)> {
        vec![
            ("none", LensDistortion::None),
            (
                "opencv",
                LensDistortion::polynomial([-0.1, 0.02, 0.0, 0.0], [1e-3, -5e-4]),
            ),
            (
                "nerfstudio opencv (k3, k4)",
                LensDistortion::polynomial([-0.12, 0.03, -0.004, 0.0005], [8e-4, 6e-4]),
            ),
            (
                "full opencv",
                LensDistortion::RadialTangential {
                    numerator: [-0.1, 0.02, 0.003, 0.0],
                    denominator: [0.01, -0.005, 0.001],
                    tangential: [1e-3, -5e-4],
                },
            ),
            (
                "fisheye",
                LensDistortion::Fisheye {
                    k: [0.05, -0.01, 0.002, -0.0005],
                },
            ),
        ]
    }

    fn sample_points() -> Vec<DVec2> {
        let mut points = Vec::new();
        for i in -8..=8 {
            for j in -6..=6 {
                points.push(DVec2::new(i as f64 * 0.1, j as f64 * 0.1 + 0.013));
            }
        }
        points.push(DVec2::ZERO);
        points
    }

    #[test]
    fn undistort_inverts_distort() {
        for (name, lens) in lenses() {
            let mut worst: f64 = 0.0;
            for p in sample_points() {
                let back = lens.undistort(lens.distort(p)).unwrap();
                worst = worst.max((back - p).length());
            }
            eprintln!("{name}: worst |undistort(distort(p)) − p| = {worst:.3e}");
            assert!(worst < 1e-9, "{name}: {worst}");
        }
    }

    #[test]
    fn analytic_jacobian_matches_finite_differences() {
        let lens = lenses()[3].1;
        let h = 1e-6;
        for p in [DVec2::new(0.3, -0.4), DVec2::new(-0.7, 0.2)] {
            let j = lens.radial_tangential_with_jacobian(p).jacobian;
            for (axis, step) in [DVec2::new(h, 0.0), DVec2::new(0.0, h)].iter().enumerate() {
                let numeric = (lens.distort(p + *step) - lens.distort(p - *step)) / (2.0 * h);
                assert!((numeric.x - j[0][axis]).abs() < 1e-8, "{p} {axis}");
                assert!((numeric.y - j[1][axis]).abs() < 1e-8, "{p} {axis}");
            }
        }
    }

    #[test]
    fn fisheye_directions_reach_beyond_ninety_degrees() {
        let lens = LensDistortion::Fisheye {
            k: [0.0, 0.0, 0.0, 0.0],
        };
        // Equidistant: a distorted radius of 2 is an angle of 2 rad (> 90°) from the axis.
        let d = lens.undistorted_direction(DVec2::new(0.0, 2.0));
        assert!((d - DVec3::new(0.0, 2f64.sin(), 2f64.cos())).length() < 1e-12);
        assert!(lens.undistort(DVec2::new(0.0, 2.0)).is_none());
    }

    #[test]
    fn radial_tangential_matches_colmap_opencv_by_hand() {
        // COLMAP OPENCV with k1 = -0.1, k2 = 0.02, p1 = 1e-3, p2 = -5e-4 at (0.3, -0.2):
        // r² = 0.13, radial = 1 − 0.013 + 0.000338 = 0.987338,
        // x_d = 0.3·0.987338 + 2·1e-3·(−0.06) − 5e-4·(0.13 + 0.18) = 0.2959264,
        // y_d = −0.2·0.987338 + 2·(−5e-4)·(−0.06) + 1e-3·(0.13 + 0.08) = −0.1971976.
        let lens = lenses()[1].1;
        let d = lens.distort(DVec2::new(0.3, -0.2));
        assert!(
            (d - DVec2::new(0.2959264, -0.1971976)).length() < 1e-14,
            "{d}"
        );
    }
}
