//! Analytic signed distance functions and the homework's SDF volume, as plain numbers: the
//! scalar maths that the fused kernel runs per sample and the float64 reference checks.

/// An analytic signed distance function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sdf {
    /// Axis-aligned box.
    Box {
        /// Centre `[x, y, z]` in world units.
        center: [f32; 3],
        /// Full side lengths along x, y and z.
        side_lengths: [f32; 3],
    },
    /// Sphere.
    Sphere {
        /// Centre `[x, y, z]` in world units.
        center: [f32; 3],
        /// Radius in world units.
        radius: f32,
    },
}

impl Sdf {
    /// The shape's centre in world coordinates.
    pub fn center(&self) -> [f32; 3] {
        match self {
            Sdf::Box { center, .. } | Sdf::Sphere { center, .. } => *center,
        }
    }

    /// Signed distance of one point (negative inside); the same maths as
    /// [`crate::kernels::sdf_volume::signed_distance`] on a single point.
    pub fn distance(&self, p: [f32; 3]) -> f32 {
        match self {
            Sdf::Box {
                center,
                side_lengths,
            } => {
                let q: [f32; 3] =
                    std::array::from_fn(|k| (p[k] - center[k]).abs() - 0.5 * side_lengths[k]);
                let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f32>().sqrt();
                let inside = q[0].max(q[1]).max(q[2]).min(0.0);
                outside + inside
            }
            Sdf::Sphere { center, radius } => {
                (0..3)
                    .map(|k| (p[k] - center[k]).powi(2))
                    .sum::<f32>()
                    .sqrt()
                    - radius
            }
        }
    }
}

/// The homework's SDF → density for one value: `α · (½·e^(−s/β) if s > 0 else 1 − ½·e^(s/β))`,
/// written with `e^(−|s|/β)` so that neither branch overflows.
pub fn sdf_to_density_scalar(sdf: f32, alpha: f64, beta: f64) -> f32 {
    let e = (sdf.abs() * (-1.0 / beta) as f32).exp();
    let d = if sdf > 0.0 { 0.5 * e } else { 1.0 - 0.5 * e };
    d * alpha as f32
}

/// The signed distance at which [`sdf_to_density_scalar`] equals `density`: its inverse,
/// `−β·ln(2d/α)` for `d ≤ α/2` and `β·ln(2(1 − d/α))` above (0 at `α/2`). `None` unless
/// `0 < density < α` (the density only reaches 0 and α at infinite distance).
pub fn sdf_at_density(density: f64, alpha: f64, beta: f64) -> Option<f64> {
    let x = density / alpha;
    if !(x > 0.0 && x < 1.0 && beta > 0.0) {
        return None;
    }
    Some(if x <= 0.5 {
        -beta * (2.0 * x).ln()
    } else {
        beta * (2.0 * (1.0 - x)).ln()
    })
}

/// The homework's density → volume density for one value: `σ = −ln(1 − density) / Δ`.
pub fn density_to_sigma_scalar(density: f32, delta: f32) -> f32 {
    -(1.0 - density).ln() / delta
}

/// A volume defined by an SDF, with the homework's colour options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SdfVolume {
    /// The shape.
    pub sdf: Sdf,
    /// Density scale α of [`sdf_to_density_scalar`], in [0, 1].
    pub alpha: f64,
    /// Falloff β of [`sdf_to_density_scalar`] in world units (> 0; smaller is sharper).
    pub beta: f64,
    /// Colour `clamp(|p − center|, 0.02, 0.98) · feature` instead of the constant feature.
    pub rainbow: bool,
    /// RGB colour (the scale of the rainbow colouring with `rainbow`).
    pub feature: [f32; 3],
}

impl SdfVolume {
    /// σ and colour of one sample: `(σ, [r, g, b])`.
    pub fn evaluate_point(&self, p: [f32; 3], delta: f32) -> (f32, [f32; 3]) {
        let density = sdf_to_density_scalar(self.sdf.distance(p), self.alpha, self.beta);
        let sigma = density_to_sigma_scalar(density, delta);
        let feature = if self.rainbow {
            let c = self.sdf.center();
            std::array::from_fn(|k| (p[k] - c[k]).abs().clamp(0.02, 0.98) * self.feature[k])
        } else {
            self.feature
        };
        (sigma, feature)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sdf_at_density_inverts_the_density() {
        for s in [-0.2f32, -0.01, 0.0, 0.03, 0.15] {
            let d = sdf_to_density_scalar(s, 0.8, 0.05) as f64;
            let back = sdf_at_density(d, 0.8, 0.05).unwrap();
            assert!((back - s as f64).abs() < 1e-5, "{s} -> {d} -> {back}");
        }
        assert_eq!(sdf_at_density(0.4, 0.8, 0.05), Some(0.0));
        for bad in [0.0, 0.8, 1.0, -0.1, f64::NAN] {
            assert_eq!(sdf_at_density(bad, 0.8, 0.05), None);
        }
    }
}
