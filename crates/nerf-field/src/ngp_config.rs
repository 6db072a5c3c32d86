//! The `ngp` field kind's config: the hash-grid field's `implicit_function` section, read
//! straight into [`NgpParams`] (the sizes [`crate::ngp`] builds its field of), with its
//! registration, its checks and the defaults its keys take.

use std::sync::Arc;

use anyhow::{ensure, Result};

use crate::appearance::AppearanceParams;
use crate::field_config::{FieldConfig, FieldKind};
use crate::trainable::FieldSpec;
use nerf_core::contraction::Contraction;
use nerf_hash_grid::hash_grid::HashGridParams;

/// The kind's name: what a config's `implicit_function.type` and a checkpoint call it.
pub const KIND: &str = "ngp";

/// The kind's registration ([`crate::registry::FIELD_KINDS`]).
pub(crate) const NGP: FieldKind = FieldKind::new::<NgpParams>(KIND, true);

/// How the raw density becomes σ ≥ 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DensityActivation {
    /// `exp(x)` with the gradient of `exp(min(x, 15))` (`trunc_exp`), as instant-ngp.
    #[default]
    TruncExp,
    /// `ln(1 + eˣ)`.
    Softplus,
}

/// `trunc_exp` or `softplus`, as a config writes it (`implicit_function.density_activation`).
impl<'de> serde::Deserialize<'de> for DensityActivation {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        nerf_core::key_checks::deserialize_name(
            d,
            &[("trunc_exp", Self::TruncExp), ("softplus", Self::Softplus)],
        )
    }
}

/// The hash-grid field as a config's `implicit_function` section with `type: ngp` writes
/// it, read straight from the section (a key left out takes its default): the grid's shape,
/// its box, density activation, scene contraction and appearance embedding. The kind's
/// registration and checks are below.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NgpParams {
    /// Levels of the hash grid `L` (`n_levels`, default 16).
    #[serde(default = "default_levels")]
    pub n_levels: usize,
    /// Features per level `F` (`n_features_per_level`, default 2).
    #[serde(default = "default_features")]
    pub n_features_per_level: usize,
    /// `log2` of the rows of each level's table `T` (`log2_hashmap_size`, default 19).
    #[serde(default = "default_log2_rows")]
    pub log2_hashmap_size: u32,
    /// Coarsest grid resolution `N_min` (`base_resolution`, default 16).
    #[serde(default = "default_base_resolution")]
    pub base_resolution: f64,
    /// Finest grid resolution `N_max` (`max_resolution`; `None`: 2048 × the box's half-size,
    /// the largest over the axes, 3072 for the default box; see [`NgpParams::grid`]).
    pub max_resolution: Option<f64>,
    /// The box the grid covers, `[[min x, y, z], [max x, y, z]]` in world units, or in
    /// contracted space with a contraction (`aabb`, default ±1.5 on every axis: the lego
    /// scene and its occupancy grid).
    #[serde(default = "default_aabb")]
    pub aabb: [[f64; 3]; 2],
    /// `trunc_exp` (default, instant-ngp) or `softplus` (`density_activation`).
    #[serde(default)]
    pub density_activation: DensityActivation,
    /// Scene contraction (`contraction`): `none` (default; the grid covers `aabb` of the
    /// world) or `linf` (unbounded scenes: points are contracted into `[-2, 2]³` first; see
    /// [`nerf_core::contraction`]).
    #[serde(default)]
    pub contraction: Contraction,
    /// Length of the vector learnt per training image and added into the colour MLP
    /// (`appearance_dim`, default 0 = none; see [`crate::appearance`]).
    #[serde(default)]
    pub appearance_dim: usize,
    /// Training images the appearance embedding has a vector for: no key of the config, but
    /// the training set's size (`FieldSpec::for_training_images`) or the checkpoint's (0
    /// until then: no embedding parameters).
    #[serde(skip)]
    pub appearance_images: usize,
}

impl NgpParams {
    /// The hash encoding's shape: the grid keys, with `max_resolution` defaulting to 2048 ×
    /// the box's largest half-size.
    pub fn grid(&self) -> HashGridParams {
        let half = (0..3)
            .map(|a| (self.aabb[1][a] - self.aabb[0][a]) / 2.0)
            .fold(0.0, f64::max);
        HashGridParams {
            n_levels: self.n_levels,
            n_features: self.n_features_per_level,
            log2_table_size: self.log2_hashmap_size,
            base_resolution: self.base_resolution,
            max_resolution: self.max_resolution.unwrap_or(2048.0 * half),
        }
    }

    /// The appearance embedding's sizes; `None` without one (`appearance_dim: 0`).
    pub(crate) fn appearance(&self) -> Option<AppearanceParams> {
        (self.appearance_dim > 0).then_some(AppearanceParams {
            dim: self.appearance_dim,
            images: self.appearance_images,
        })
    }

    /// Checks the grid and that the box has positive extent on every axis.
    pub(crate) fn validate(&self) -> Result<()> {
        self.grid().validate()?;
        ensure!(
            (0..3).all(|a| self.aabb[1][a] > self.aabb[0][a]),
            "implicit_function.aabb: max must exceed min on every axis, got {:?}",
            self.aabb
        );
        Ok(())
    }
}

impl FieldConfig for NgpParams {
    fn kind(&self) -> &'static str {
        NGP.name
    }

    fn validate(&self) -> Result<()> {
        NgpParams::validate(self)
    }

    fn field_spec(&self) -> Option<Result<Arc<dyn FieldSpec>>> {
        Some(
            NgpParams::validate(self)
                .map(|()| Arc::new(self.clone()) as Arc<dyn FieldSpec>),
        )
    }

    fn contraction(&self) -> Contraction {
        self.contraction
    }
}

/// `n_levels`: 16 levels.
fn default_levels() -> usize {
    16
}
/// `n_features_per_level`: 2 features.
fn default_features() -> usize {
    2
}
/// `log2_hashmap_size`: 2^19 rows a level.
fn default_log2_rows() -> u32 {
    19
}
/// `base_resolution`: 16 cells a side at the coarsest level.
fn default_base_resolution() -> f64 {
    16.0
}
/// `aabb`: ±1.5 on every axis.
fn default_aabb() -> [[f64; 3]; 2] {
    [[-1.5; 3], [1.5; 3]]
}
