//! A registry of built-in kinds that a config names by its `type` (fields, samplers): a
//! `'static` list searched by name, whose names the messages list.

use crate::term::or_list;

/// A registered kind: what a config's `type` calls it.
pub trait Named {
    /// The name a config writes.
    fn name(&self) -> &'static str;
}

/// The kind of `kinds` called `name`.
pub fn find_named<K: Named>(kinds: &'static [K], name: &str) -> Option<&'static K> {
    kinds.iter().find(|k| k.name() == name)
}

/// The names of `kinds` as a message lists them: `a, b or c`.
pub fn listed_names<'a, K: Named + 'a>(kinds: impl IntoIterator<Item = &'a K>) -> String {
    let names: Vec<&str> = kinds.into_iter().map(Named::name).collect();
    or_list(&names)
}

/// A name that two of `kinds` share (`None` when each is registered once).
pub fn repeated_name<K: Named>(kinds: &[K]) -> Option<&'static str> {
    kinds.iter().enumerate().find_map(|(i, k)| {
        kinds[..i]
            .iter()
            .any(|earlier| earlier.name() == k.name())
            .then(|| k.name())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Kind(&'static str);
    impl Named for Kind {
        fn name(&self) -> &'static str {
            self.0
        }
    }
    const KINDS: &[Kind] = &[Kind("a"), Kind("b"), Kind("c")];

    #[test]
    fn kinds_are_found_by_name_and_listed() {
        assert_eq!(find_named(KINDS, "b").map(Named::name), Some("b"));
        assert!(find_named(KINDS, "d").is_none());
        assert_eq!(listed_names(KINDS), "a, b or c");
        assert_eq!(listed_names(&KINDS[..1]), "a");
        assert_eq!(repeated_name(KINDS), None);
        assert_eq!(repeated_name(&[Kind("a"), Kind("b"), Kind("a")]), Some("a"));
    }
}
