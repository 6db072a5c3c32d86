//! The `implicit_function` section: the field kind its `type` names, read as that kind's own
//! config. The kinds and their configs live beside the fields ([`nerf_field::registry`]);
//! what a config asks of its field at run time is [`super::field_section`]'s.

use std::fmt;

use anyhow::{anyhow, Result};
use serde_yaml_ng::Value;

use super::messages::key_error;
use nerf_field::field_config::FieldConfig;
use nerf_field::registry::{find_kind, kind_names};

/// The typed `implicit_function` section: the config of the kind its `type` names.
pub struct ImplicitFunctionConfig(Box<dyn FieldConfig>);

impl ImplicitFunctionConfig {
    /// The `implicit_function` section as written, typed by its `type`; errors name the key
    /// (`implicit_function.…`) and list the registered kinds.
    pub(crate) fn from_section(section: Value) -> Result<Self> {
        let name = section
            .get("type")
            .and_then(Value::as_str)
            .ok_or_else(|| anyhow!("implicit_function.type: missing ({})", kind_names(false)))?;
        let kind = find_kind(name).ok_or_else(|| {
            anyhow!(
                "implicit_function.type: unknown type `{name}` (expected {})",
                kind_names(false)
            )
        })?;
        let config = (kind.parse)(section).map_err(|e| key_error(e, "implicit_function"))?;
        Ok(Self(config))
    }

    /// The kind's config, whatever the kind.
    pub(crate) fn field(&self) -> &dyn FieldConfig {
        &*self.0
    }

    /// The kind's name (`implicit_function.type`).
    pub fn kind(&self) -> &'static str {
        self.0.kind()
    }

    /// The config as the kind `T`'s own, when the section names that kind.
    pub fn get<T: FieldConfig>(&self) -> Option<&T> {
        self.0.as_any().downcast_ref()
    }

    /// The config as the kind `T`'s own, to change, when the section names that kind.
    pub fn get_mut<T: FieldConfig>(&mut self) -> Option<&mut T> {
        self.0.as_any_mut().downcast_mut()
    }

    /// Whether the section describes a field rendered from its own parameters (the analytic
    /// SDF volume, no checkpoint) rather than a trainable field loaded from a checkpoint.
    pub fn is_sdf_volume(&self) -> bool {
        find_kind(self.kind()).is_some_and(|kind| !kind.trainable)
    }
}

impl Clone for ImplicitFunctionConfig {
    fn clone(&self) -> Self {
        Self(self.0.clone_box())
    }
}

impl PartialEq for ImplicitFunctionConfig {
    fn eq(&self, other: &Self) -> bool {
        self.0.same_as(other.field())
    }
}

impl fmt::Debug for ImplicitFunctionConfig {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}
