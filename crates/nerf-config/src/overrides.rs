//! Hydra-style `key.sub=value` overrides, applied to the YAML tree before it is typed.

use anyhow::{anyhow, bail, Result};
use serde_yaml_ng::{Mapping, Value};

use super::messages::{one_line, quoted};
use super::ConfigError;
use crate::yaml_bounds;

/// Applies one `key.sub=value` override; the value is parsed as YAML. An error
/// ([`ConfigError::Override`]) is one line that starts with ``override `key=value`:`` and says
/// what is wrong with it.
pub fn apply_override(root: &mut Value, assignment: &str) -> Result<(), ConfigError> {
    apply_override_inner(root, assignment).map_err(|e| ConfigError::Override {
        assignment: assignment.to_string(),
        message: format!("override `{}`: {e:#}", quoted(assignment)),
    })
}

fn apply_override_inner(root: &mut Value, assignment: &str) -> Result<()> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| anyhow!("not of the form key.sub=value"))?;
    // Hydra's `+key=value` (add a key) and `++key=value` (add or override): keys are added
    // as needed here anyway, so the prefix is accepted and dropped.
    let key = key.trim().trim_start_matches('+');
    if key.is_empty() || key.split('.').any(str::is_empty) {
        bail!("empty key");
    }
    if key.split('.').count() > yaml_bounds::MAX_YAML_DEPTH {
        bail!(
            "the key has more than {} parts",
            yaml_bounds::MAX_YAML_DEPTH
        );
    }
    yaml_bounds::check_yaml_bounds(raw, "the value")?;
    let value: Value = serde_yaml_ng::from_str(raw)
        .map_err(|e| anyhow!("cannot parse the value: {}", one_line(&e.to_string())))?;
    let parts: Vec<&str> = key.split('.').collect();
    let mut node = root;
    for (i, part) in parts.iter().enumerate() {
        let map = match node {
            Value::Mapping(m) => m,
            Value::Null => {
                *node = Value::Mapping(Mapping::new());
                match node {
                    Value::Mapping(m) => m,
                    _ => unreachable!(),
                }
            }
            _ => bail!("`{}` is not a section", parts[..i].join(".")),
        };
        let k = Value::String((*part).to_string());
        if i + 1 == parts.len() {
            map.insert(k, value);
            return Ok(());
        }
        node = map.entry(k).or_insert(Value::Null);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::test_box_with as box_with;

    #[test]
    fn overrides_change_values() {
        let c = box_with(&[
            "sampler.n_pts_per_ray=32",
            "data.image_size=[200,150]",
            "renderer.white_background=True",
        ])
        .unwrap();
        assert_eq!(c.sampler.n_pts_per_ray, 32);
        assert_eq!(c.image_size(), (200, 150));
        assert!(c.renderer.white_background);
        let c = box_with(&[
            "implicit_function.sdf.type=sphere",
            "implicit_function.sdf.radius.val=0.8",
        ])
        .unwrap();
        assert!(matches!(
            c.sdf_volume().unwrap().sdf,
            nerf_core::sdf::Sdf::Sphere { .. }
        ));
    }
}
