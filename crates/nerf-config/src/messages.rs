//! The words of config errors: deserialiser messages in a config writer's terms, keys named
//! by their dotted path, and a bad value blamed on the override or the file line it came from.

use anyhow::Result;
use serde::de::DeserializeOwned;
use serde_yaml_ng::Value;

use super::{Config, ConfigError};
use nerf_field::field_config::SectionError;

/// Deserialises `value` into `T`; an error is a [`ConfigError::Invalid`] that starts with the
/// dotted key path.
pub(super) fn from_value<T: DeserializeOwned>(
    value: Value,
    prefix: &str,
) -> Result<T, ConfigError> {
    serde_path_to_error::deserialize(value).map_err(|e| key_error(e, prefix))
}

/// A deserialiser error as a [`ConfigError::Invalid`] whose one-line message names the dotted
/// key it failed at, below `prefix` (the config's top level when empty).
pub(super) fn key_error(e: SectionError, prefix: &str) -> ConfigError {
    let path = e.path().to_string();
    let key = match (prefix.is_empty(), path == ".") {
        (true, true) => "config".to_string(),
        (true, false) => path,
        (false, true) => prefix.to_string(),
        (false, false) => format!("{prefix}.{path}"),
    };
    let key = one_line(&key);
    let message = format!(
        "{key}: {}",
        one_line(&in_user_words(&e.into_inner().to_string()))
    );
    ConfigError::Invalid { key, message }
}

/// A deserialiser message with Rust type names replaced by what a config writer knows:
/// "expected usize" → "expected a whole number", "expected struct SamplerSettings" → "expected a
/// section of `key: value` lines", and so on.
pub fn in_user_words(message: &str) -> String {
    let mut m = message.to_string();
    for (rust, words) in [
        ("usize", "a whole number"),
        ("u64", "a whole number"),
        ("u32", "a whole number"),
        ("f64", "a number"),
        ("f32", "a number"),
        ("a sequence", "a list"),
    ] {
        m = m.replace(&format!("expected {rust}"), &format!("expected {words}"));
    }
    if let Some(i) = m.find("expected struct ") {
        let end = m[i + 16..]
            .find(|c: char| !c.is_alphanumeric() && c != '_')
            .map_or(m.len(), |j| i + 16 + j);
        m.replace_range(i..end, "expected a section of `key: value` lines");
    }
    if let Some(i) = m.find("expected an array of length ") {
        let rest = &m[i + 28..];
        let n: String = rest.chars().take_while(char::is_ascii_digit).collect();
        let end = i + 28 + n.len();
        m.replace_range(i..end, &format!("expected a list of {n} values"));
    }
    m
}

/// `s` with its control characters escaped, so that a message quoting it stays on one line.
pub(super) fn one_line(s: &str) -> String {
    s.chars()
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect()
}

/// `s` for quoting in a message: on one line ([`one_line`]) and cut to its first 100
/// characters (an override can be as long as the command line).
pub(super) fn quoted(s: &str) -> String {
    let mut out = one_line(s);
    if let Some((i, _)) = out.char_indices().nth(100) {
        out.truncate(i);
        out.push('…');
    }
    out
}

/// Says where a bad value came from: the first override whose addition makes the config fail
/// (`override `key=value`: …`), or else the file, with the line of the offending key when it
/// can be found (`config FILE, line N: …`).
pub(super) fn blame(
    text: &str,
    origin: &str,
    overrides: &[String],
    error: anyhow::Error,
) -> anyhow::Error {
    if format!("{error:#}").starts_with("override `") {
        // An override that could not be applied names itself already.
        return error;
    }
    if Config::from_yaml(text, &[]).is_ok() {
        for n in 1..=overrides.len() {
            if Config::from_yaml(text, &overrides[..n]).is_err() {
                return error.context(format!("override `{}`", quoted(&overrides[n - 1])));
            }
        }
    }
    let message = format!("{error:#}");
    let key = message.split(':').next().unwrap_or("");
    match key_line(text, key) {
        Some(line) => error.context(format!("config {origin}, line {line}")),
        None => error.context(format!("config {origin}")),
    }
}

/// The 1-based line of `key` (dotted, e.g. `sampler.n_pts_per_ray`) in YAML `text`: each part
/// found in order, deeper than the one before. `None` when some part is not found.
fn key_line(text: &str, key: &str) -> Option<usize> {
    let lines: Vec<&str> = text.lines().collect();
    let (mut from, mut indent, mut found) = (0usize, -1i64, None);
    for part in key.split('.').map(|p| p.split('[').next().unwrap_or(p)) {
        let hit = (from..lines.len()).find(|&i| {
            let l = lines[i];
            let depth = (l.len() - l.trim_start().len()) as i64;
            depth > indent && l.trim_start().starts_with(&format!("{part}:"))
        })?;
        indent = (lines[hit].len() - lines[hit].trim_start().len()) as i64;
        from = hit + 1;
        found = Some(hit + 1);
    }
    found
}

/// `one` or `many` by `n`.
pub fn plural<'a>(n: usize, one: &'a str, many: &'a str) -> &'a str {
    if n == 1 {
        one
    } else {
        many
    }
}
