//! A field kind the crate does not ship, written against its public seams only: a dense voxel
//! grid of raw density and colour, trilinearly interpolated (Plenoxels without spherical
//! harmonics). [`VoxelSpec`] is its sizes ([`nerf::FieldSpec`]), [`VoxelModel`] its parameters
//! ([`nerf::TrainableField`]), [`VoxelField`] what the renderer queries ([`nerf::Field`]).
//!
//! Shared by `examples/custom_field/main.rs` and `apps/nerf/tests/custom_field.rs`.

use std::sync::Arc;

use anyhow::Result;
use candle_core::{DType, Device, Tensor, D};
use candle_nn::VarMap;
use nerf::config::Config;
use nerf::field::trainable::{
    named_vars, seed_uniform, BoxedField, DenseGroup, ParamGroups, SparseRowsGroup,
};
use nerf::{Field, FieldOutput, FieldSpec, RaySamples, TrainSettings, TrainableField};

/// A config's NeRF training settings with the model swapped for `spec`: no occupancy grid,
/// fixed rays per step, one epoch, the grid's learning rate (0.05), no previews.
pub fn train_settings(config: &Config, spec: VoxelSpec) -> Result<TrainSettings> {
    let mut settings = config.train_settings()?;
    settings.model = Arc::new(spec);
    settings.grid = None;
    settings.samples_per_step = None;
    settings.num_epochs = 1;
    settings.lr = 0.05;
    settings.render_interval = usize::MAX;
    Ok(settings)
}

/// The parameter's name in checkpoints.
pub const VOXELS: &str = "voxels";

/// A grid of `resolution³` voxels over the cube `[-half_extent, half_extent]³`.
#[derive(Debug, Clone, Copy)]
pub struct VoxelSpec {
    /// Voxels along each axis (at least 2).
    pub resolution: usize,
    /// Half the cube's side, in world units.
    pub half_extent: f32,
}

impl FieldSpec for VoxelSpec {
    fn kind(&self) -> &'static str {
        "voxels"
    }

    fn seeded(&self, seed: u64, device: &Device) -> Result<Box<dyn TrainableField>> {
        anyhow::ensure!(
            self.resolution >= 2,
            "a voxel grid needs at least 2 voxels a side"
        );
        let varmap = VarMap::new();
        varmap.get(
            (self.resolution.pow(3), 4),
            VOXELS,
            candle_nn::Init::Const(0.0),
            DType::F32,
            device,
        )?;
        // Raw values U(-0.1, 0.1): faint density, grey colour.
        seed_uniform(&varmap, seed, |_, _| 0.1, device)?;
        Ok(Box::new(VoxelModel {
            spec: *self,
            varmap,
        }))
    }
}

/// The grid's parameters: `voxels` `(R³, 4)`, raw density then raw RGB per voxel, voxel
/// `(x, y, z)` at row `x·R² + y·R + z`.
pub struct VoxelModel {
    spec: VoxelSpec,
    varmap: VarMap,
}

impl VoxelModel {
    fn voxels(&self) -> Tensor {
        named_vars(&self.varmap)[0].1.as_tensor().clone()
    }
}

impl TrainableField for VoxelModel {
    fn kind(&self) -> &'static str {
        "voxels"
    }

    fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    fn training_field(&self, _: f64) -> BoxedField {
        Box::new(VoxelField {
            spec: self.spec,
            voxels: self.voxels(),
        })
    }

    fn render_field(&self) -> BoxedField {
        Box::new(VoxelField {
            spec: self.spec,
            voxels: self.voxels().detach(),
        })
    }

    fn density(&self, points: &Tensor) -> Result<Tensor> {
        let field = VoxelField {
            spec: self.spec,
            voxels: self.voxels().detach(),
        };
        Ok(field.values(points)?.0)
    }

    /// Each step touches the voxels around its samples only: sparse Adam on the grid's rows,
    /// the gradient coming through autograd.
    fn param_groups(&self) -> ParamGroups {
        let (name, var) = named_vars(&self.varmap).remove(0);
        ParamGroups {
            dense: DenseGroup::pytorch(Vec::new()),
            sparse_rows: vec![SparseRowsGroup::instant_ngp(name, var, None)],
        }
    }
}

/// The grid as a radiance field.
pub struct VoxelField {
    spec: VoxelSpec,
    voxels: Tensor,
}

impl VoxelField {
    /// Density `(M, 1)` (softplus of the raw value, 0 outside the cube) and colour `(M, 3)`
    /// (sigmoid) at points `(M, 3)`.
    fn values(&self, points: &Tensor) -> Result<(Tensor, Tensor)> {
        let (r, h) = (self.spec.resolution, self.spec.half_extent as f64);
        let scale = (r - 1) as f64 / (2.0 * h);
        let g = points.affine(scale, h * scale)?;
        let inside = g
            .ge(0.0)?
            .mul(&g.le((r - 1) as f64)?)?
            .to_dtype(DType::F32)?
            .min_keepdim(D::Minus1)?;
        // The lower corner stops one voxel short of the far side, so every corner exists.
        let g = g.clamp(0.0, (r - 1) as f64 - 1e-3)?;
        let base = g.floor()?;
        let frac = (&g - &base)?;
        let stride = Tensor::new(&[[(r * r) as f32], [r as f32], [1.0]], points.device())?;
        let mut sum: Option<Tensor> = None;
        for corner in 0..8usize {
            let offset: Vec<f32> = (0..3).map(|a| ((corner >> (2 - a)) & 1) as f32).collect();
            let offset = Tensor::new(offset.as_slice(), points.device())?.unsqueeze(0)?;
            let index = base
                .broadcast_add(&offset)?
                .matmul(&stride)?
                .squeeze(1)?
                .to_dtype(DType::U32)?;
            // Weight: frac along the axes where the corner is the upper one, 1 − frac elsewhere.
            let per_axis = frac.broadcast_mul(&offset)?.add(
                &frac
                    .ones_like()?
                    .sub(&frac)?
                    .broadcast_mul(&(1.0 - &offset)?)?,
            )?;
            let weight = (per_axis.narrow(1, 0, 1)? * per_axis.narrow(1, 1, 1)?)?
                .mul(&per_axis.narrow(1, 2, 1)?)?;
            let value = self
                .voxels
                .index_select(&index, 0)?
                .broadcast_mul(&weight)?;
            sum = Some(match sum {
                Some(s) => (s + value)?,
                None => value,
            });
        }
        let raw = sum.expect("eight corners");
        let density = softplus(&raw.narrow(1, 0, 1)?)?.mul(&inside)?;
        let colour = candle_nn::ops::sigmoid(&raw.narrow(1, 1, 3)?)?;
        Ok((density, colour))
    }
}

/// `ln(1 + eˣ)`, computed as `max(x, 0) + ln(1 + e^−|x|)` so it never overflows.
fn softplus(x: &Tensor) -> Result<Tensor> {
    Ok((x.relu()? + x.abs()?.neg()?.exp()?.affine(1.0, 1.0)?.log()?)?)
}

impl Field for VoxelField {
    fn evaluate(
        &self,
        samples: &RaySamples,
        _deltas: &Tensor,
        _directions: &Tensor,
    ) -> Result<FieldOutput> {
        let (n, s, _) = samples.points.dims3()?;
        let (density, colour) = self.values(&samples.points.reshape((n * s, 3))?)?;
        Ok(FieldOutput {
            density: density.reshape((n, s, 1))?,
            feature: colour.reshape((n, s, 3))?,
        })
    }
}
