//! Lens distortion on the normalised image plane, as COLMAP and nerfstudio model it: one
//! file per lens model, each with the COLMAP camera models that use it.
//!
//! A camera-space point `(X, Y, Z)` (OpenCV axes: +x right, +y down, +z forward) lands on the
//! normalised plane at `p = (X / Z, Y / Z)`; the lens moves it to the distorted point
//! `distort(p)`, which the intrinsics then scale and shift into pixels. Undistortion inverts
//! `distort` (by Newton's method where there is no closed form, to a residual of 1e-10 or
//! better).
//!
//! The models: [`NoDistortion`] (`no_distortion.rs`), [`RadialTangential`]
//! (Brown–Conrady, `radial_tangential.rs`), [`Fisheye`] (Kannala–Brandt, `fisheye.rs`) and
//! [`FieldOfView`] (Devernay–Faugeras, `field_of_view.rs`).
//! A new model is one file (its maths, its `LensModel` impl and its COLMAP models) and one
//! line of the `lens_models!` list below.

use glam::{DVec2, DVec3};

mod lens_model;

pub use lens_model::ColmapCameraModel;
pub(crate) use lens_model::LensModel;

/// Declares each lens model's module, the [`LensDistortion`] enum with one variant per model,
/// its dispatch to the models' [`LensModel`] impls, and the COLMAP models they read.
macro_rules! lens_models {
    ($($variant:ident => $module:ident::$model:ident,)+) => {
        $(mod $module; pub use $module::$model;)+

        /// How a lens moves points on the normalised image plane: one variant per lens model
        /// (more may come, hence `non_exhaustive`).
        #[derive(Debug, Clone, Copy, PartialEq)]
        #[non_exhaustive]
        pub enum LensDistortion {
            $(
                #[doc = concat!("The `", stringify!($module), "` lens model.")]
                $variant($model),
            )+
        }

        impl LensDistortion {
            /// The lens behind the trait every model implements.
            fn lens_model(&self) -> &dyn LensModel {
                match self {
                    $(Self::$variant(lens) => lens,)+
                }
            }
        }

        /// Every COLMAP camera model a lens model reads, in COLMAP's id order.
        pub fn colmap_camera_models() -> Vec<&'static ColmapCameraModel> {
            let mut models: Vec<&ColmapCameraModel> =
                [$($module::COLMAP_MODELS,)+].into_iter().flatten().collect();
            models.sort_by_key(|m| m.id);
            models
        }
    };
}

lens_models! {
    None => no_distortion::NoDistortion,
    RadialTangential => radial_tangential::RadialTangential,
    Fisheye => fisheye::Fisheye,
    FieldOfView => field_of_view::FieldOfView,
}

impl LensDistortion {
    /// An ideal pinhole: `distort(p) = p`.
    pub const NONE: Self = Self::None(NoDistortion);

    /// Radial and tangential distortion with a plain polynomial radial term
    /// `1 + k₁r² + k₂r⁴ + k₃r⁶ + k₄r⁸`.
    pub fn polynomial(radial: [f64; 4], tangential: [f64; 2]) -> Self {
        Self::RadialTangential(RadialTangential {
            numerator: radial,
            denominator: [0.0; 3],
            tangential,
        })
    }

    /// Every coefficient, for finiteness checks.
    pub fn coefficients(&self) -> Vec<f64> {
        self.lens_model().coefficients()
    }

    /// Whether the lens images angles rather than tangents (a fisheye).
    pub fn is_fisheye(&self) -> bool {
        self.lens_model().is_fisheye()
    }

    /// The distorted normalised point of the undistorted normalised point `p`.
    pub(crate) fn distort(&self, p: DVec2) -> DVec2 {
        self.lens_model().distort(p)
    }

    /// The undistorted normalised point whose distortion is `distorted`, or `None` when it
    /// has none: a fisheye ray 90° or more from the optical axis. Where Newton cannot reach
    /// the tolerance (a fold of the distortion, far outside any calibrated field) this is the
    /// iterate with the smallest residual.
    pub(crate) fn undistort(&self, distorted: DVec2) -> Option<DVec2> {
        self.lens_model().undistort(distorted)
    }

    /// The unit camera-space direction (OpenCV axes) of the ray imaged at the distorted
    /// normalised point `distorted`. Unlike [`Self::undistort`] this exists for fisheye rays
    /// at or beyond 90° from the axis too (`z ≤ 0`).
    pub(crate) fn undistorted_direction(&self, distorted: DVec2) -> DVec3 {
        self.lens_model().undistorted_direction(distorted)
    }

    /// Whether the lens maps one ray to each of `points` (distorted normalised points, spread
    /// over an image): at each, undistortion converges (`distort(undistort(d))` within `1e-9 ·
    /// (1 + |d|)` of `d`) and the distortion keeps its orientation there (a positive Jacobian
    /// determinant; for a fisheye, `θ_d` rising with `θ`, below 180°). Newton failing to
    /// converge is this error, never a silent fallback to the distorted point. The error says
    /// which point failed and how.
    pub(crate) fn check_invertible_at(&self, points: &[DVec2]) -> Result<(), String> {
        let lens = self.lens_model();
        points
            .iter()
            .try_for_each(|&d| lens.check_invertible_at(d, 1e-9 * (1.0 + d.length())))
    }
}

#[cfg(test)]
mod tests;
