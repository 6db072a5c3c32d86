//! The `nerf` field kind's config: the homework's NeRF MLP, with the homework's keys and
//! defaults ([`crate::nerf`]).

use std::sync::Arc;

use anyhow::{bail, Result};
use serde::de::IgnoredAny;
use serde::Deserialize;

use crate::field_config::{FieldConfig, FieldKind};
use crate::nerf::NerfParams;
use crate::trainable::FieldSpec;
use nerf_core::key_checks::{count_in_range, finite};

/// The kind's registration ([`crate::registry::FIELD_KINDS`]).
pub(crate) const NERF: FieldKind = FieldKind::new::<NerfConfig>(crate::nerf::KIND, true);

/// Most harmonic functions of a positional embedding (2^31 is past f32 precision).
pub(crate) const HARMONICS: usize = 32;
/// Widest hidden layer.
pub(crate) const HIDDEN: usize = 4096;
/// Deepest trunk.
pub(crate) const LAYERS: usize = 64;

/// `implicit_function` with `type: nerf` (the homework's keys and defaults).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NerfConfig {
    /// `implicit_function.type`, which chose this kind.
    #[serde(rename = "type")]
    pub kind: IgnoredAny,
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

impl NerfConfig {
    /// The model's sizes.
    pub fn params(&self) -> NerfParams {
        NerfParams {
            n_harmonic_functions_xyz: self.n_harmonic_functions_xyz,
            n_harmonic_functions_dir: self.n_harmonic_functions_dir,
            n_hidden_neurons_xyz: self.n_hidden_neurons_xyz,
            n_hidden_neurons_dir: self.n_hidden_neurons_dir,
            n_layers_xyz: self.n_layers_xyz,
            append_xyz: self.append_xyz.clone(),
        }
    }
}

impl FieldConfig for NerfConfig {
    fn kind(&self) -> &'static str {
        NERF.name
    }

    fn validate(&self) -> Result<()> {
        let n = self;
        let p = "implicit_function";
        count_in_range(
            &format!("{p}.n_hidden_neurons_xyz"),
            n.n_hidden_neurons_xyz,
            HIDDEN,
        )?;
        count_in_range(
            &format!("{p}.n_hidden_neurons_dir"),
            n.n_hidden_neurons_dir,
            HIDDEN,
        )?;
        count_in_range(&format!("{p}.n_layers_xyz"), n.n_layers_xyz, LAYERS)?;
        for (key, v) in [
            ("n_harmonic_functions_xyz", n.n_harmonic_functions_xyz),
            ("n_harmonic_functions_dir", n.n_harmonic_functions_dir),
        ] {
            if v > HARMONICS {
                bail!("{p}.{key}: must be at most {} (got {v})", HARMONICS);
            }
        }
        finite(&format!("{p}.density_noise_std"), n.density_noise_std)?;
        if n.density_noise_std < 0.0 {
            bail!("{p}.density_noise_std: must be non-negative");
        }
        if let Some(bad) = n
            .append_xyz
            .iter()
            .find(|&&i| i == 0 || i >= n.n_layers_xyz)
        {
            bail!(
                "{p}.append_xyz: layer {bad} is out of range 1..{}",
                n.n_layers_xyz
            );
        }
        Ok(())
    }

    fn field_spec(&self) -> Option<Result<Arc<dyn FieldSpec>>> {
        Some(Ok(Arc::new(self.params())))
    }

    fn density_noise(&self) -> f64 {
        self.density_noise_std
    }
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
