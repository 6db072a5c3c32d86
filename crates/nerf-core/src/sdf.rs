//! Analytic signed distance functions and the homework's SDF volume, as plain numbers. The
//! volume's per-sample maths (SDF → density → σ, colour, and their derivatives) is in
//! `nerf_kernels::sdf_point`, beside the fused kernels that run it.

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
    #[inline]
    /// The shape's centre in world coordinates.
    pub fn center(&self) -> [f32; 3] {
        match self {
            Sdf::Box { center, .. } | Sdf::Sphere { center, .. } => *center,
        }
    }

    #[inline]
    /// Signed distance of one point (negative inside); the same maths as
    /// `nerf::kernels::sdf_volume::signed_distance` on a single point.
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

/// A volume defined by an SDF, with the homework's colour options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SdfVolume {
    /// The shape.
    pub sdf: Sdf,
    /// Density scale α of the homework's SDF → density `α · (½e^(−s/β) if s > 0 else 1 − ½e^(s/β))`, in [0, 1].
    pub alpha: f64,
    /// Falloff β of the SDF → density in world units (> 0; smaller is sharper).
    pub beta: f64,
    /// Colour `clamp(|p − center|, 0.02, 0.98) · feature` instead of the constant feature.
    pub rainbow: bool,
    /// RGB colour (the scale of the rainbow colouring with `rainbow`).
    pub feature: [f32; 3],
}

impl SdfVolume {
    /// The homework's box scene (`box.yaml`): a cube of side 1.75 at the origin, α = 1,
    /// β = 0.05, rainbow colours at full scale.
    pub fn homework_box() -> Self {
        SdfVolume {
            sdf: Sdf::Box {
                center: [0.0; 3],
                side_lengths: [1.75; 3],
            },
            alpha: 1.0,
            beta: 0.05,
            rainbow: true,
            feature: [1.0; 3],
        }
    }
}
