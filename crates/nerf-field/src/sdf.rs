//! The homework's SDF volume as a field: a box or sphere SDF, turned into density and σ, with a
//! constant or rainbow colour. Each parameter the config marks `opt: True` is a trainable
//! variable; the others are constants.

use anyhow::Result;
use candle_core::{Device, Tensor, Var};
use candle_nn::VarMap;

use crate::trainable::{BoxedField, TrainableField, TrainingFastPaths};
use nerf_core::rays::Rays;
use nerf_core::sdf::{Sdf, SdfVolume};
use nerf_kernels::sdf_render::sdf_render_mse;
use nerf_kernels::sdf_volume::{sdf_volume, SdfTensors, ShapeTensors};
use nerf_render::field::{Composited, Field, FieldFastPaths, FieldOutput};
use nerf_render::sampler::RaySamples;

/// Which parameters of an SDF volume are trained (the homework's `opt` flags). `side_lengths`
/// applies to a box, `radius` to a sphere.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SdfTrainable {
    /// Train the shape's centre (`implicit_function.sdf.center.opt`).
    pub center: bool,
    /// Train the box's side lengths (`implicit_function.sdf.side_lengths.opt`).
    pub side_lengths: bool,
    /// Train the sphere's radius (`implicit_function.sdf.radius.opt`).
    pub radius: bool,
    /// Train α (`implicit_function.alpha.opt`).
    pub alpha: bool,
    /// Train β (`implicit_function.beta.opt`).
    pub beta: bool,
    /// Train the colour (`implicit_function.feature.opt`).
    pub feature: bool,
}

/// An SDF volume field.
#[derive(Debug, Clone)]
pub struct SdfField {
    /// The parameters as tensors (variables where trainable).
    pub params: SdfTensors,
    /// The trainable parameters by name (`center`, `side_lengths`, `radius`, `alpha`, `beta`,
    /// `feature`), in that order.
    pub variables: Vec<(String, Var)>,
}

impl SdfField {
    /// A field with every parameter constant.
    pub fn fixed(volume: &SdfVolume, device: &Device) -> Result<Self> {
        Self::new(volume, SdfTrainable::default(), device)
    }

    /// A field of `volume`'s values whose `trainable` parameters are variables.
    pub(crate) fn new(
        volume: &SdfVolume,
        trainable: SdfTrainable,
        device: &Device,
    ) -> Result<Self> {
        let mut variables = Vec::new();
        let mut param = |name: &str, values: &[f32], train: bool| -> Result<Tensor> {
            let t = Tensor::new(values, device)?;
            if !train {
                return Ok(t);
            }
            let v = Var::from_tensor(&t)?;
            variables.push((name.to_string(), v.clone()));
            Ok(v.as_tensor().clone())
        };
        let shape = match volume.sdf {
            Sdf::Box {
                center,
                side_lengths,
            } => ShapeTensors::Box {
                center: param("center", &center, trainable.center)?,
                side_lengths: param("side_lengths", &side_lengths, trainable.side_lengths)?,
            },
            Sdf::Sphere { center, radius } => ShapeTensors::Sphere {
                center: param("center", &center, trainable.center)?,
                radius: param("radius", &[radius], trainable.radius)?,
            },
        };
        let alpha = param("alpha", &[volume.alpha as f32], trainable.alpha)?;
        let beta = param("beta", &[volume.beta as f32], trainable.beta)?;
        let feature = param("feature", &volume.feature, trainable.feature)?;
        Ok(Self {
            params: SdfTensors {
                shape,
                alpha,
                beta,
                rainbow: volume.rainbow,
                feature,
            },
            variables,
        })
    }

    /// Holds each trainable parameter inside the range where the volume is defined, after an
    /// optimiser step: α in [0, 1] (above 1 the density exceeds 1 and σ = −ln(1 − density) is
    /// NaN), β, side lengths and radius at least 1e-6. The homework does not clamp; an
    /// unclamped step past these bounds would make its loss NaN.
    pub(crate) fn clamp_to_valid(&self) -> Result<()> {
        for (name, var) in &self.variables {
            let (lo, hi) = match name.as_str() {
                "alpha" => (0.0, 1.0),
                "beta" | "side_lengths" | "radius" => (1e-6, f64::MAX),
                _ => continue,
            };
            var.set(&var.as_tensor().clamp(lo, hi)?)?;
        }
        Ok(())
    }

    /// The current parameter values as plain numbers.
    pub fn values(&self) -> Result<SdfVolume> {
        self.params.values()
    }
}

/// The SDF volume as a trainable model (the homework's box fit): its field and the
/// parameters marked `opt: True`, by name.
pub struct SdfModel {
    /// The field, its trainable parameters as variables.
    pub field: SdfField,
    varmap: VarMap,
}

impl SdfModel {
    /// `volume`'s values with its `trainable` parameters as variables.
    pub fn new(volume: &SdfVolume, trainable: SdfTrainable, device: &Device) -> Result<Self> {
        Ok(Self::from_field(SdfField::new(volume, trainable, device)?))
    }

    /// The model of `field`'s variables.
    pub fn from_field(field: SdfField) -> Self {
        let varmap = VarMap::new();
        {
            let mut data = varmap.data().lock().expect("varmap lock");
            for (name, var) in &field.variables {
                data.insert(name.clone(), var.clone());
            }
        }
        Self { field, varmap }
    }
}

impl TrainableField for SdfModel {
    fn kind(&self) -> &'static str {
        "sdf_volume"
    }

    fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// The field itself: its variables are tracked. (An SDF volume has no density noise.)
    fn training_field(&self, _: f64) -> BoxedField {
        Box::new(self.field.clone())
    }

    /// Every parameter a constant of its current value: no gradient graph, and the fused
    /// kernels can run.
    fn render_field(&self) -> BoxedField {
        Box::new(SdfField {
            params: self.field.params.detach(),
            variables: Vec::new(),
        })
    }

    /// σ for a unit sample spacing, `−ln(1 − density)`.
    fn density(&self, points: &Tensor) -> Result<Tensor> {
        let points = points.unsqueeze(1)?;
        let deltas = points.narrow(2, 0, 1)?.ones_like()?;
        let params = self.field.params.detach();
        Ok(sdf_volume(&points, &deltas, &params)?.0.squeeze(1)?)
    }

    /// α in [0, 1]; β, side lengths and radius at least 1e-6 (`SdfField::clamp_to_valid`).
    fn constrain(&self) -> Result<()> {
        self.field.clamp_to_valid()
    }

    fn fast_paths(&self) -> Option<&dyn TrainingFastPaths> {
        Some(self)
    }
}

impl TrainingFastPaths for SdfModel {
    /// The fused SDF render-and-loss kernel (`kernels::sdf_render::sdf_render_mse`).
    fn fused_mse(
        &self,
        rays: &Rays,
        lengths: &Tensor,
        target: &Tensor,
        white_background: bool,
    ) -> Result<Option<Tensor>> {
        sdf_render_mse(rays, lengths, target, &self.field.params, white_background)
    }
}

impl Field for SdfField {
    fn evaluate(
        &self,
        samples: &RaySamples,
        deltas: &Tensor,
        _directions: &Tensor,
    ) -> Result<FieldOutput> {
        let (density, feature) = sdf_volume(&samples.points, deltas, &self.params)?;
        Ok(FieldOutput { density, feature })
    }

    fn fast_paths(&self) -> Option<&dyn FieldFastPaths> {
        Some(self)
    }
}

impl FieldFastPaths for SdfField {
    fn max_samples_per_chunk(&self) -> usize {
        // A few floats per sample: 2^22 samples are about 250 MB over all of a chunk's
        // tensors; the homework's box frame, 256² rays × 64 points, fits in one.
        1 << 22
    }

    fn render_fused(&self, rays: &Rays, lengths: &Tensor) -> Result<Option<Composited>> {
        nerf_kernels::sdf_render::sdf_render(rays, lengths, &self.params)
    }
}
