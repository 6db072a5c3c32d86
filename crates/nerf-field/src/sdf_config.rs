//! The `sdf_volume` field kind's config: the homework's analytic SDF volume (a box or a
//! sphere, its density and colour), each parameter `{val, opt}`; rendered from these values,
//! or fitted where `opt: True` ([`crate::sdf`]).

use std::sync::Arc;

use anyhow::{bail, Result};
use serde::Deserialize;

use crate::field_config::{FieldConfig, FieldKind};
use crate::sdf::SdfTrainable;
use crate::trainable::FieldSpec;
use nerf_core::key_checks::finite;
use nerf_core::sdf::{Sdf, SdfVolume};

/// The kind's registration ([`crate::registry::FIELD_KINDS`]).
pub(crate) const SDF_VOLUME: FieldKind = FieldKind::new::<SdfVolumeConfig>("sdf_volume", false);

/// A homework parameter `{val, opt}`; `opt` marks it trainable in the homework.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Param<T> {
    /// The value.
    pub val: T,
    /// Trainable in the homework (`opt: True`); default false.
    #[serde(default)]
    pub opt: bool,
}

/// `implicit_function.sdf.type`.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SdfKind {
    /// `box`: an axis-aligned box with `side_lengths`.
    Box,
    /// `sphere`: a sphere with `radius`.
    Sphere,
}

/// `implicit_function.sdf`: the shape (`box` with `side_lengths`, or `sphere` with `radius`).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SdfShapeConfig {
    /// `implicit_function.sdf.type`: `box` or `sphere`.
    #[serde(rename = "type")]
    pub kind: SdfKind,
    /// `implicit_function.sdf.center`: the shape's centre `[x, y, z]` in world units.
    pub center: Param<[f64; 3]>,
    /// `implicit_function.sdf.side_lengths`: the box's full side lengths (required for a box).
    pub side_lengths: Option<Param<[f64; 3]>>,
    /// `implicit_function.sdf.radius`: the sphere's radius (required for a sphere).
    pub radius: Option<Param<f64>>,
}

/// `implicit_function.feature`: a constant colour, or the homework's rainbow colouring.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FeatureConfig {
    /// `implicit_function.feature.rainbow`: colour `clamp(|p − center|, 0.02, 0.98) · val`
    /// instead of the constant `val` (default false).
    #[serde(default)]
    pub rainbow: bool,
    /// `implicit_function.feature.val`: the RGB colour (the rainbow colouring's scale).
    pub val: [f64; 3],
    /// `implicit_function.feature.opt`: train the colour (default false).
    #[serde(default)]
    pub opt: bool,
}

/// `implicit_function` with `type: sdf_volume`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SdfVolumeConfig {
    /// `implicit_function.sdf`: the shape.
    pub sdf: SdfShapeConfig,
    /// `implicit_function.feature`: the colour.
    pub feature: FeatureConfig,
    /// `implicit_function.alpha`: the density scale α of the SDF → density map, in [0, 1].
    pub alpha: Param<f64>,
    /// `implicit_function.beta`: the SDF → density falloff β in world units (> 0).
    pub beta: Param<f64>,
}

impl SdfVolumeConfig {
    /// The SDF volume's initial values.
    pub fn volume(&self) -> Result<SdfVolume> {
        let s = self;
        let center = s.sdf.center.val.map(|v| v as f32);
        // Validation guarantees the shape's own key is present.
        let sdf = match (s.sdf.kind, &s.sdf.side_lengths, &s.sdf.radius) {
            (SdfKind::Box, Some(sides), _) => Sdf::Box {
                center,
                side_lengths: sides.val.map(|v| v as f32),
            },
            (SdfKind::Sphere, _, Some(radius)) => Sdf::Sphere {
                center,
                radius: radius.val as f32,
            },
            (SdfKind::Box, None, _) => {
                bail!("implicit_function.sdf.side_lengths: required for a box")
            }
            (SdfKind::Sphere, _, None) => {
                bail!("implicit_function.sdf.radius: required for a sphere")
            }
        };
        Ok(SdfVolume {
            sdf,
            alpha: s.alpha.val,
            beta: s.beta.val,
            rainbow: s.feature.rainbow,
            feature: s.feature.val.map(|v| v as f32),
        })
    }

    /// Which SDF parameters the config marks `opt: True`. An error names an `opt: True` on
    /// a parameter the shape does not have (a box's `radius`, a sphere's `side_lengths`).
    pub fn trainable(&self) -> Result<SdfTrainable> {
        let s = self;
        let p = "implicit_function.sdf";
        match s.sdf.kind {
            SdfKind::Box if s.sdf.radius.as_ref().is_some_and(|r| r.opt) => {
                bail!("{p}.radius.opt: a box has no radius to train (it has side_lengths)")
            }
            SdfKind::Sphere if s.sdf.side_lengths.as_ref().is_some_and(|r| r.opt) => {
                bail!(
                    "{p}.side_lengths.opt: a sphere has no side lengths to train (it has a radius)"
                )
            }
            _ => {}
        }
        Ok(SdfTrainable {
            center: s.sdf.center.opt,
            side_lengths: s.sdf.side_lengths.as_ref().is_some_and(|p| p.opt),
            radius: s.sdf.radius.as_ref().is_some_and(|p| p.opt),
            alpha: s.alpha.opt,
            beta: s.beta.opt,
            feature: s.feature.opt,
        })
    }
}

impl FieldConfig for SdfVolumeConfig {
    fn kind(&self) -> &'static str {
        SDF_VOLUME.name
    }

    fn validate(&self) -> Result<()> {
        let s = self;
        let p = "implicit_function";
        for (i, v) in s.sdf.center.val.iter().enumerate() {
            finite(&format!("{p}.sdf.center.val[{i}]"), *v)?;
        }
        for (i, v) in s.feature.val.iter().enumerate() {
            finite(&format!("{p}.feature.val[{i}]"), *v)?;
        }
        finite(&format!("{p}.alpha.val"), s.alpha.val)?;
        finite(&format!("{p}.beta.val"), s.beta.val)?;
        if !(0.0..=1.0).contains(&s.alpha.val) {
            bail!("{p}.alpha.val: must be in [0, 1] (got {})", s.alpha.val);
        }
        if s.beta.val <= 0.0 {
            bail!("{p}.beta.val: must be positive (got {})", s.beta.val);
        }
        match s.sdf.kind {
            SdfKind::Box => {
                let Some(sides) = &s.sdf.side_lengths else {
                    bail!("{p}.sdf.side_lengths: required for a box");
                };
                for (i, v) in sides.val.iter().enumerate() {
                    finite(&format!("{p}.sdf.side_lengths.val[{i}]"), *v)?;
                    if *v <= 0.0 {
                        bail!("{p}.sdf.side_lengths.val[{i}]: must be positive (got {v})");
                    }
                }
            }
            SdfKind::Sphere => {
                let Some(radius) = &s.sdf.radius else {
                    bail!("{p}.sdf.radius: required for a sphere");
                };
                finite(&format!("{p}.sdf.radius.val"), radius.val)?;
                if radius.val <= 0.0 {
                    bail!("{p}.sdf.radius.val: must be positive (got {})", radius.val);
                }
            }
        }
        Ok(())
    }

    fn field_spec(&self) -> Option<Result<Arc<dyn FieldSpec>>> {
        None
    }
}
