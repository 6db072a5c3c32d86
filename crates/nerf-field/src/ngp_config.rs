//! The `ngp` field kind's config: the hash-grid field's sizes, its box, density activation,
//! scene contraction and appearance embedding ([`crate::ngp`]).

use std::sync::Arc;

use anyhow::Result;
use serde::de::IgnoredAny;
use serde::Deserialize;

use crate::appearance::AppearanceParams;
use crate::field_config::{FieldConfig, FieldKind};
use crate::ngp::{DensityActivation, NgpParams};
use crate::trainable::FieldSpec;
use nerf_core::contraction::Contraction;

/// The kind's registration ([`crate::registry::FIELD_KINDS`]).
pub(crate) const NGP: FieldKind = FieldKind::new::<NgpConfig>(crate::ngp::KIND, true);

/// `implicit_function` with `type: ngp`: the hash-grid field ([`crate::ngp`]).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NgpConfig {
    /// `implicit_function.type`, which chose this kind.
    #[serde(rename = "type")]
    pub kind: IgnoredAny,
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
    pub density_activation: DensityActivation,
    /// Scene contraction (`contraction`): `none` (default; the grid covers `aabb` of the
    /// world) or `linf` (unbounded scenes: points are contracted into `[-2, 2]³` first, and
    /// `aabb`, like the occupancy grid's, is in contracted space; see
    /// [`nerf_core::contraction`]).
    #[serde(default)]
    pub contraction: Contraction,
    /// Length of the appearance embedding learnt per training image (`appearance_dim`,
    /// default 0 = none; see [`crate::appearance`]).
    #[serde(default)]
    pub appearance_dim: usize,
}

impl NgpConfig {
    /// The field's sizes (an error for a bad grid or box).
    pub fn params(&self) -> Result<NgpParams> {
        let half = (0..3)
            .map(|a| (self.aabb[1][a] - self.aabb[0][a]) / 2.0)
            .fold(0.0, f64::max);
        let params = NgpParams {
            grid: nerf_hash_grid::hash_grid::HashGridParams {
                n_levels: self.n_levels,
                n_features: self.n_features_per_level,
                log2_table_size: self.log2_hashmap_size,
                base_resolution: self.base_resolution,
                max_resolution: self.max_resolution.unwrap_or(2048.0 * half),
            },
            aabb: self.aabb,
            density_activation: self.density_activation,
            contraction: self.contraction,
            // The number of images is the training set's, known when it is loaded
            // (FieldSpec::for_training_images) or read from a checkpoint.
            appearance: (self.appearance_dim > 0).then_some(AppearanceParams {
                dim: self.appearance_dim,
                images: 0,
            }),
        };
        params.validate()?;
        Ok(params)
    }
}

impl FieldConfig for NgpConfig {
    fn kind(&self) -> &'static str {
        NGP.name
    }

    fn validate(&self) -> Result<()> {
        self.params().map(|_| ())
    }

    fn field_spec(&self) -> Option<Result<Arc<dyn FieldSpec>>> {
        Some(self.params().map(|p| Arc::new(p) as Arc<dyn FieldSpec>))
    }

    fn contraction(&self) -> Contraction {
        self.contraction
    }
}

fn d2() -> usize {
    2
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
