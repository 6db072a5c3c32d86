//! The `ngp` field kind's config: the hash-grid field, whose `implicit_function` section
//! reads straight into [`NgpParams`]; here are its registration, its checks and the
//! defaults its keys take.

use std::sync::Arc;

use anyhow::Result;

use crate::field_config::{FieldConfig, FieldKind};
use crate::ngp::NgpParams;
use crate::trainable::FieldSpec;
use nerf_core::contraction::Contraction;

/// The kind's registration ([`crate::registry::FIELD_KINDS`]).
pub(crate) const NGP: FieldKind = FieldKind::new::<NgpParams>(crate::ngp::KIND, true);

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
pub(crate) fn default_levels() -> usize {
    16
}
/// `n_features_per_level`: 2 features.
pub(crate) fn default_features() -> usize {
    2
}
/// `log2_hashmap_size`: 2^19 rows a level.
pub(crate) fn default_log2_rows() -> u32 {
    19
}
/// `base_resolution`: 16 cells a side at the coarsest level.
pub(crate) fn default_base_resolution() -> f64 {
    16.0
}
/// `aabb`: ±1.5 on every axis.
pub(crate) fn default_aabb() -> [[f64; 3]; 2] {
    [[-1.5; 3], [1.5; 3]]
}
