//! What a field kind's config is ([`FieldConfig`]) and how a kind is registered
//! ([`FieldKind`]); the list of kinds is [`crate::registry`].

use std::any::Any;
use std::fmt::Debug;
use std::sync::Arc;

use anyhow::Result;
use serde::de::DeserializeOwned;
use serde_yaml_ng::Value;

use crate::trainable::FieldSpec;
use nerf_core::contraction::Contraction;

/// A deserialiser error with the path of the key it failed at.
pub type SectionError = serde_path_to_error::Error<serde_yaml_ng::Error>;

/// A field kind as a config names it.
#[derive(Debug, Clone, Copy)]
pub struct FieldKind {
    /// The section's `type` that names the kind.
    pub name: &'static str,
    /// Whether the kind trains (a [`FieldSpec`]) rather than rendering from the parameters
    /// the config writes, as the homework's SDF volume does.
    pub trainable: bool,
    /// The `implicit_function` section (a YAML mapping) as the kind's typed config.
    pub parse: fn(Value) -> Result<Box<dyn FieldConfig>, SectionError>,
}

impl nerf_core::registry::Named for FieldKind {
    fn name(&self) -> &'static str {
        self.name
    }
}

impl FieldKind {
    /// The kind `name` whose config is `T`, read with serde.
    pub(crate) const fn new<T: FieldConfig + DeserializeOwned>(
        name: &'static str,
        trainable: bool,
    ) -> Self {
        Self {
            name,
            trainable,
            parse: parse_as::<T>,
        }
    }
}

fn parse_as<T: FieldConfig + DeserializeOwned>(
    section: Value,
) -> Result<Box<dyn FieldConfig>, SectionError> {
    Ok(Box::new(serde_path_to_error::deserialize::<_, T>(section)?))
}

/// A field kind's typed config: the `implicit_function` section of a config that names it.
pub trait FieldConfig: ConfigObject + Debug + Send + Sync {
    /// The kind's name (its [`FieldKind::name`]).
    fn kind(&self) -> &'static str;

    /// Checks every value's range, an error naming the key (`implicit_function.…`) of the
    /// first bad one.
    fn validate(&self) -> Result<()>;

    /// The trainable field's sizes; `None` for a kind rendered from the config's own
    /// parameters (the SDF volume).
    fn field_spec(&self) -> Option<Result<Arc<dyn FieldSpec>>>;

    /// How the field maps world points into its grid's space; the occupancy grid tests
    /// points in the same space.
    fn contraction(&self) -> Contraction {
        Contraction::None
    }

    /// The standard deviation of the noise added to the raw density in training.
    fn density_noise(&self) -> f64 {
        0.0
    }
}

/// What a boxed [`FieldConfig`] needs to be cloned, compared and looked into; implemented
/// for every config type that is `Clone + PartialEq`.
pub trait ConfigObject: Any {
    /// A boxed copy.
    fn clone_box(&self) -> Box<dyn FieldConfig>;
    /// Whether `other` is the same kind with the same values.
    fn same_as(&self, other: &dyn FieldConfig) -> bool;
    /// The config as `Any`, to look at a kind's own keys.
    fn as_any(&self) -> &dyn Any;
    /// The config as mutable `Any`.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl<T: FieldConfig + Clone + PartialEq> ConfigObject for T {
    fn clone_box(&self) -> Box<dyn FieldConfig> {
        Box::new(self.clone())
    }

    fn same_as(&self, other: &dyn FieldConfig) -> bool {
        other.as_any().downcast_ref::<T>() == Some(self)
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}
