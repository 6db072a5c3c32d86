//! The sampler kinds a config's `sampler.type` can name, listed once ([`SAMPLER_KINDS`]): each
//! kind is defined beside its sampler, and registering it is one line here. The messages that
//! list the kinds are written from this list. What a kind is:
//! [`crate::sampler_kind`].

use crate::sampler_kind::SamplerKind;
use nerf_core::registry::{find_named, listed_names};

/// The built-in sampler kinds, the default first: one line each.
pub const SAMPLER_KINDS: &[SamplerKind] = &[
    crate::hierarchical::STRATIFIED,
    crate::disparity_sampler::DEPTH_THEN_DISPARITY,
];

/// The registered kind called `name`.
pub fn find_sampler_kind(name: &str) -> Option<&'static SamplerKind> {
    find_named(SAMPLER_KINDS, name)
}

/// The registered kinds' names as a message lists them: `stratified or depth_then_disparity`.
pub fn sampler_kind_names() -> String {
    listed_names(SAMPLER_KINDS)
}

/// `sampler.type` left out: the first registered kind, the homework's `stratified`.
impl Default for &'static SamplerKind {
    fn default() -> Self {
        &SAMPLER_KINDS[0]
    }
}

/// `sampler.type`: the registered kind of that name; an error listing the kinds for another.
impl<'de> serde::Deserialize<'de> for &'static SamplerKind {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        find_sampler_kind(&name).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "unknown `{name}` (expected {})",
                sampler_kind_names()
            ))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_is_registered_once_and_listed() {
        assert_eq!(nerf_core::registry::repeated_name(SAMPLER_KINDS), None);
        assert_eq!(sampler_kind_names(), "stratified or depth_then_disparity");
        assert!(find_sampler_kind("pdf").is_none());
    }
}
