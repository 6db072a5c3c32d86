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
    /// The `implicit_function` section (a YAML mapping) as the kind's typed config; its
    /// `type` key, which named the kind, is not passed on.
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

/// The section read as `T`, without its `type` (which chose `T`, and so is no key of it).
fn parse_as<T: FieldConfig + DeserializeOwned>(
    mut section: Value,
) -> Result<Box<dyn FieldConfig>, SectionError> {
    if let Value::Mapping(keys) = &mut section {
        keys.remove("type");
    }
    serde_path_to_error::deserialize::<_, T>(section)
        .map(|config| Box::new(config) as Box<dyn FieldConfig>)
        .map_err(with_type_key)
}

/// `error` with `type` among the keys that an unknown key's message lists: the section's
/// `type` is one of its keys, though `T` does not hold it. serde lists one key as
/// ``expected `a` ``, two as ``expected `a` or `b` `` and more as ``expected one of `a`, `b`,
/// `c` ``.
fn with_type_key(error: SectionError) -> SectionError {
    const EXPECTED: &str = ", expected ";
    let message = error.inner().to_string();
    // The listed names are identifiers: the last `, expected ` is serde's, not the key's.
    let Some(i) = message
        .starts_with("unknown field `")
        .then(|| message.rfind(EXPECTED))
        .flatten()
    else {
        return error;
    };
    let (head, listed) = message.split_at(i + EXPECTED.len());
    let listed = if let Some(rest) = listed.strip_prefix("one of ") {
        format!("one of `type`, {rest}")
    } else if let Some((a, b)) = listed.split_once(" or ") {
        format!("one of `type`, {a}, {b}")
    } else {
        format!("`type` or {listed}")
    };
    let inner = serde::de::Error::custom(format!("{head}{listed}"));
    SectionError::new(error.path().clone(), inner)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, PartialEq, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct One {
        #[allow(dead_code)]
        a: Option<u8>,
    }

    #[derive(Debug, Clone, PartialEq, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Two {
        #[allow(dead_code)]
        a: Option<u8>,
        #[allow(dead_code)]
        b: Option<u8>,
    }

    fn unknown_key_message<T: serde::de::DeserializeOwned + std::fmt::Debug>() -> String {
        let section: Value = serde_yaml_ng::from_str("{type: t, zz: 1}").unwrap();
        let mut section = section;
        if let Value::Mapping(keys) = &mut section {
            keys.remove("type");
        }
        let error = serde_path_to_error::deserialize::<_, T>(section).unwrap_err();
        with_type_key(error).inner().to_string()
    }

    #[test]
    fn an_unknown_key_lists_type_among_the_expected_keys() {
        assert_eq!(
            unknown_key_message::<One>(),
            "unknown field `zz`, expected `type` or `a`"
        );
        assert_eq!(
            unknown_key_message::<Two>(),
            "unknown field `zz`, expected one of `type`, `a`, `b`"
        );
        let many = unknown_key_message::<crate::nerf::NerfParams>();
        assert!(
            many.starts_with(
                "unknown field `zz`, expected one of `type`, `n_harmonic_functions_xyz`"
            ),
            "{many}"
        );
    }
}
