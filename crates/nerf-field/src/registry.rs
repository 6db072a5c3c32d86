//! The field kinds a config's `implicit_function.type` can name, listed once
//! (`FIELD_KINDS`): each kind's config (its section's schema, checks and what it becomes
//! at run time) lives beside the field, in the kind's own file, and registering it is one
//! line of the `field_kinds!` list in the crate's `lib.rs`, which also declares the file's
//! module. The config layer asks this list which kinds exist, and every message that lists
//! them is written from it. What a kind is: [`crate::field_config`].

use crate::field_config::FieldKind;
use nerf_core::registry::{find_named, listed_names};

/// Declares each kind's module (`module::KIND`: the file `module.rs`, which defines the
/// `FieldKind` constant `KIND`) and lists the kinds, in order, as the crate's `KINDS`.
macro_rules! field_kinds {
    ($($module:ident::$kind:ident),* $(,)?) => {
        $(pub mod $module;)*
        /// The registered kinds, in the order of the `field_kinds!` list.
        pub(crate) const KINDS: &[$crate::field_config::FieldKind] = &[$($module::$kind),*];
    };
}

/// The built-in field kinds, in the order messages list them (the `field_kinds!` list of the
/// crate's `lib.rs`: one line each).
pub(crate) const FIELD_KINDS: &[FieldKind] = crate::KINDS;

/// The registered kind called `name`.
pub fn find_kind(name: &str) -> Option<&'static FieldKind> {
    find_named(FIELD_KINDS, name)
}

/// The names of the registered kinds (only the trainable ones when `trainable_only`) as a
/// message lists them: `sdf_volume, nerf or ngp`.
pub fn kind_names(trainable_only: bool) -> String {
    listed_names(
        FIELD_KINDS
            .iter()
            .filter(|k| k.trainable || !trainable_only),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_is_registered_once_and_listed() {
        assert_eq!(nerf_core::registry::repeated_name(FIELD_KINDS), None);
        assert_eq!(kind_names(false), "sdf_volume, nerf or ngp");
        assert_eq!(kind_names(true), "nerf or ngp");
        assert!(find_kind("mesh").is_none());
    }
}
