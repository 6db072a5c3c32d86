//! Range checks that name the key of a bad value: what every config section's validation
//! (and every field kind's, `nerf::field::registry`) shares.

use anyhow::{bail, Result};

/// An error naming `key` when `v` is not a finite number.
pub fn finite(key: &str, v: f64) -> Result<()> {
    if !v.is_finite() {
        bail!("{key}: must be a finite number (got {v})");
    }
    Ok(())
}

/// An error naming `key` when `v` is not in `1..=max`.
pub fn count_in_range(key: &str, v: usize, max: usize) -> Result<()> {
    if v == 0 || v > max {
        bail!("{key}: must be 1 to {max} (got {v})");
    }
    Ok(())
}

/// The message for a name that is none of `expected`: `` unknown `name` (expected a, b or
/// c) ``, as every config key that takes one of a few names says it.
pub fn unknown_name(name: &str, expected: &[&str]) -> String {
    format!(
        "unknown `{name}` (expected {})",
        crate::term::or_list(expected)
    )
}

/// Deserialises a value written as one of a few names: the value of the name `d` holds among
/// `names`, else the [`unknown_name`] error.
pub fn deserialize_name<'de, D: serde::Deserializer<'de>, T: Copy>(
    d: D,
    names: &[(&str, T)],
) -> std::result::Result<T, D::Error> {
    let name = <String as serde::Deserialize>::deserialize(d)?;
    match names.iter().find(|(n, _)| *n == name) {
        Some(&(_, value)) => Ok(value),
        None => {
            let expected: Vec<&str> = names.iter().map(|(n, _)| *n).collect();
            Err(serde::de::Error::custom(unknown_name(&name, &expected)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_list_what_is_expected() {
        assert_eq!(unknown_name("x", &["a"]), "unknown `x` (expected a)");
        assert_eq!(
            unknown_name("x", &["a", "b"]),
            "unknown `x` (expected a or b)"
        );
        assert_eq!(
            unknown_name("x", &["a", "b", "c"]),
            "unknown `x` (expected a, b or c)"
        );
    }
}
