//! The `nerf` field kind's config: the homework's NeRF MLP, whose `implicit_function`
//! section reads straight into [`NerfParams`] (the homework's keys and defaults); here are
//! its registration and the ranges its keys must keep.

use std::sync::Arc;

use anyhow::{bail, Result};

use crate::field_config::{FieldConfig, FieldKind};
use crate::nerf::NerfParams;
use crate::trainable::FieldSpec;
use nerf_core::key_checks::{count_in_range, finite};

/// The kind's registration ([`crate::registry::FIELD_KINDS`]).
pub(crate) const NERF: FieldKind = FieldKind::new::<NerfParams>(crate::nerf::KIND, true);

/// Most harmonic functions of a positional embedding (2^31 is past f32 precision).
pub(crate) const HARMONICS: usize = 32;
/// Widest hidden layer.
pub(crate) const HIDDEN: usize = 4096;
/// Deepest trunk.
pub(crate) const LAYERS: usize = 64;

impl FieldConfig for NerfParams {
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
        Some(Ok(Arc::new(self.clone())))
    }

    fn density_noise(&self) -> f64 {
        self.density_noise_std
    }
}
