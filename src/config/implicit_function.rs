//! The `implicit_function` section's schema: an analytic SDF volume, the homework's NeRF or
//! the hash-grid field, typed by the section's `type`. What each becomes at run time is
//! [`super::field_section`]'s.

use anyhow::{anyhow, Result};
use serde::{Deserialize, Deserializer};
use serde_yaml_ng::Value;

use super::messages::from_value;

/// `implicit_function.type`: which field the section describes.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ImplicitFunctionKind {
    /// `sdf_volume`: an analytic SDF volume.
    SdfVolume,
    /// `nerf`: the homework's NeRF.
    Nerf,
    /// `ngp`: the hash-grid field.
    Ngp,
}

impl ImplicitFunctionKind {
    /// The name a config writes for this kind (`implicit_function.type`).
    pub fn name(self) -> &'static str {
        match self {
            Self::SdfVolume => "sdf_volume",
            Self::Nerf => "nerf",
            Self::Ngp => "ngp",
        }
    }

    /// The kind named by the section's `type`; an error naming `implicit_function.type` when
    /// it is missing (or not a string) or names no kind.
    pub fn of_section(section: &Value) -> Result<Self> {
        let name = section
            .get("type")
            .and_then(Value::as_str)
            .ok_or_else(|| anyhow!("implicit_function.type: missing (sdf_volume, nerf or ngp)"))?;
        serde_yaml_ng::from_value(Value::String(name.to_string())).map_err(|_| {
            anyhow!(
                "implicit_function.type: unknown type `{name}` (expected sdf_volume, nerf or ngp)"
            )
        })
    }
}

/// The typed `implicit_function` section.
#[derive(Debug, Clone, PartialEq)]
pub enum ImplicitFunctionConfig {
    /// `type: sdf_volume`: an analytic SDF volume.
    SdfVolume(SdfVolumeConfig),
    /// `type: nerf`: the homework's NeRF.
    Nerf(NerfConfig),
    /// `type: ngp`: the hash-grid field.
    Ngp(NgpConfig),
}

impl ImplicitFunctionConfig {
    /// The `implicit_function` section as written, typed by its `type` ([`ImplicitFunctionKind`]);
    /// errors name the key (`implicit_function.…`).
    pub fn from_section(section: Value) -> Result<Self> {
        let prefix = "implicit_function";
        Ok(match ImplicitFunctionKind::of_section(&section)? {
            ImplicitFunctionKind::SdfVolume => Self::SdfVolume(from_value(section, prefix)?),
            ImplicitFunctionKind::Nerf => Self::Nerf(from_value(section, prefix)?),
            ImplicitFunctionKind::Ngp => Self::Ngp(from_value(section, prefix)?),
        })
    }

    /// Whether the section describes the analytic SDF volume (rendered from its parameters,
    /// no checkpoint) rather than a trainable field loaded from a checkpoint.
    pub fn is_sdf_volume(&self) -> bool {
        matches!(self, Self::SdfVolume(_))
    }

    /// The kind of field described.
    pub fn kind(&self) -> ImplicitFunctionKind {
        match self {
            Self::SdfVolume(_) => ImplicitFunctionKind::SdfVolume,
            Self::Nerf(_) => ImplicitFunctionKind::Nerf,
            Self::Ngp(_) => ImplicitFunctionKind::Ngp,
        }
    }
}

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
    /// `implicit_function.type`: `sdf_volume`.
    #[serde(rename = "type")]
    pub kind: ImplicitFunctionKind,
    /// `implicit_function.sdf`: the shape.
    pub sdf: SdfShapeConfig,
    /// `implicit_function.feature`: the colour.
    pub feature: FeatureConfig,
    /// `implicit_function.alpha`: the density scale α of the SDF → density map, in [0, 1].
    pub alpha: Param<f64>,
    /// `implicit_function.beta`: the SDF → density falloff β in world units (> 0).
    pub beta: Param<f64>,
}

/// `implicit_function` with `type: nerf` (the homework's keys and defaults).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NerfConfig {
    /// `implicit_function.type`: `nerf`.
    #[serde(rename = "type")]
    pub kind: ImplicitFunctionKind,
    /// Harmonic frequencies of the point embedding (`n_harmonic_functions_xyz`, default 6).
    #[serde(default = "d6")]
    pub n_harmonic_functions_xyz: usize,
    /// Harmonic frequencies of the direction embedding (`n_harmonic_functions_dir`, default 2).
    #[serde(default = "d2")]
    pub n_harmonic_functions_dir: usize,
    /// Width of the `mlp_xyz` trunk layers (`n_hidden_neurons_xyz`, default 128).
    #[serde(default = "d128")]
    pub n_hidden_neurons_xyz: usize,
    /// Width of the colour head's hidden layer (`n_hidden_neurons_dir`, default 64).
    #[serde(default = "d64")]
    pub n_hidden_neurons_dir: usize,
    /// Std of the Gaussian noise added to the raw density in training (`density_noise_std`,
    /// default 0).
    #[serde(default)]
    pub density_noise_std: f64,
    /// Layers of the `mlp_xyz` trunk (`n_layers_xyz`, default 6).
    #[serde(default = "d6")]
    pub n_layers_xyz: usize,
    /// Trunk layers before which the point embedding is concatenated again (`append_xyz`,
    /// default `[3]`).
    #[serde(default = "default_append_xyz")]
    pub append_xyz: Vec<usize>,
}

/// `implicit_function` with `type: ngp`: the hash-grid field ([`crate::field::ngp`]).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NgpConfig {
    /// `implicit_function.type`: `ngp`.
    #[serde(rename = "type")]
    pub kind: ImplicitFunctionKind,
    /// Levels of the hash grid `L` (`n_levels`, default 16).
    #[serde(default = "d16")]
    pub n_levels: usize,
    /// Features per level `F` (`n_features_per_level`, default 2).
    #[serde(default = "d2")]
    pub n_features_per_level: usize,
    /// `log2` of the rows of each level's table `T` (`log2_hashmap_size`, default 19).
    #[serde(default = "d19")]
    pub log2_hashmap_size: u32,
    /// Coarsest grid resolution `N_min` (`base_resolution`, default 16).
    #[serde(default = "d16f")]
    pub base_resolution: f64,
    /// Finest grid resolution `N_max` (`max_resolution`; default 2048 × the box's half-size,
    /// the largest over the axes: 3072 for the default box).
    pub max_resolution: Option<f64>,
    /// The box the grid covers, `[[min x, y, z], [max x, y, z]]` in world units (`aabb`,
    /// default ±1.5 on every axis: the lego scene and its occupancy grid).
    #[serde(default = "default_ngp_aabb")]
    pub aabb: [[f64; 3]; 2],
    /// `trunc_exp` (default, instant-ngp) or `softplus` (`density_activation`).
    #[serde(default)]
    pub density_activation: DensityActivationName,
    /// Scene contraction (`contraction`): `none` (default; the grid covers `aabb` of the
    /// world) or `linf` (unbounded scenes: points are contracted into `[-2, 2]³` first, and
    /// `aabb`, like the occupancy grid's, is in contracted space; see
    /// [`crate::core::contraction`]).
    #[serde(default)]
    pub contraction: ContractionName,
    /// Length of the appearance embedding learnt per training image (`appearance_dim`,
    /// default 0 = none; see [`crate::field::appearance`]).
    #[serde(default)]
    pub appearance_dim: usize,
}

/// `implicit_function.contraction` of an `ngp` field.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ContractionName(pub crate::core::contraction::Contraction);

impl<'de> Deserialize<'de> for ContractionName {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        use crate::core::contraction::Contraction;
        let name = String::deserialize(d)?;
        match name.as_str() {
            "none" => Ok(Self(Contraction::None)),
            "linf" => Ok(Self(Contraction::LInf)),
            other => Err(serde::de::Error::custom(format!(
                "unknown `{other}` (expected none or linf)"
            ))),
        }
    }
}

/// `implicit_function.density_activation` of an `ngp` field: how the raw density becomes σ.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum DensityActivationName {
    /// `trunc_exp` (the default, instant-ngp's).
    #[default]
    TruncExp,
    /// `softplus`.
    Softplus,
}

impl<'de> Deserialize<'de> for DensityActivationName {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        match name.as_str() {
            "trunc_exp" => Ok(Self::TruncExp),
            "softplus" => Ok(Self::Softplus),
            other => Err(serde::de::Error::custom(format!(
                "unknown `{other}` (expected trunc_exp or softplus)"
            ))),
        }
    }
}

fn d16() -> usize {
    16
}
fn d16f() -> f64 {
    16.0
}
fn d19() -> u32 {
    19
}
fn default_ngp_aabb() -> [[f64; 3]; 2] {
    [[-1.5; 3], [1.5; 3]]
}
fn d2() -> usize {
    2
}
fn d6() -> usize {
    6
}
fn d64() -> usize {
    64
}
fn d128() -> usize {
    128
}
fn default_append_xyz() -> Vec<usize> {
    vec![3]
}
