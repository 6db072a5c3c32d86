//! Where a config's text comes from: a file path, `configs/NAME.yaml`, or a config built into
//! the binary.

use std::path::Path;

use crate::yaml_bounds::MAX_YAML_BYTES;
use crate::ConfigError;

/// Configs shipped with the binary, found by name when `configs/NAME.yaml` is not on disk.
const BUILT_IN: &[(&str, &str)] = &[
    ("box", include_str!("../../../configs/box.yaml")),
    ("sphere", include_str!("../../../configs/sphere.yaml")),
    ("lego", include_str!("../../../configs/lego.yaml")),
    ("nerf_lego", include_str!("../../../configs/nerf_lego.yaml")),
    (
        "nerf_lego_fast",
        include_str!("../../../configs/nerf_lego_fast.yaml"),
    ),
    (
        "nerf_lego_highres",
        include_str!("../../../configs/nerf_lego_highres.yaml"),
    ),
    (
        "nerf_lego_render",
        include_str!("../../../configs/nerf_lego_render.yaml"),
    ),
    ("train_box", include_str!("../../../configs/train_box.yaml")),
    (
        "nerf_lego_ngp",
        include_str!("../../../configs/nerf_lego_ngp.yaml"),
    ),
    ("lego_ngp", include_str!("../../../configs/lego_ngp.yaml")),
    (
        "nerf_lego_ngp_400",
        include_str!("../../../configs/nerf_lego_ngp_400.yaml"),
    ),
    (
        "lego_ngp_400",
        include_str!("../../../configs/lego_ngp_400.yaml"),
    ),
    (
        "nerf_scene",
        include_str!("../../../configs/nerf_scene.yaml"),
    ),
    (
        "nerf_scene_bounded",
        include_str!("../../../configs/nerf_scene_bounded.yaml"),
    ),
    // The name nerf_scene had while a bounded config held the other; kept for old commands.
    (
        "nerf_scene_unbounded",
        include_str!("../../../configs/nerf_scene.yaml"),
    ),
];

/// The text of the config file `path`: a regular file of at most [`MAX_YAML_BYTES`], UTF-8
/// (else [`ConfigError::Unreadable`]).
fn read_config_file(path: &Path) -> Result<String, ConfigError> {
    let bytes = nerf_files::bounded_read::read_regular_file(path, "config", MAX_YAML_BYTES as u64)
        .map_err(|e| ConfigError::unreadable(path, &e))?;
    String::from_utf8(bytes).map_err(|_| ConfigError::Unreadable {
        path: path.to_path_buf(),
        message: format!("config {} is not UTF-8 text", path.display()),
    })
}

/// The YAML text for `--config NAME_OR_PATH`: an existing file path, `configs/NAME.yaml`, or a
/// built-in config of that name, and where it came from (the path, or `built-in NAME`).
/// Errors: [`ConfigError::NotFound`], [`ConfigError::Unreadable`].
pub fn config_text(name_or_path: &str) -> Result<(String, String), ConfigError> {
    let path = Path::new(name_or_path);
    if path.is_file() {
        return Ok((read_config_file(path)?, path.display().to_string()));
    }
    let looks_like_path = name_or_path.contains('/')
        || name_or_path.ends_with(".yaml")
        || name_or_path.ends_with(".yml");
    if looks_like_path && path.is_dir() {
        return Err(ConfigError::Unreadable {
            path: path.to_path_buf(),
            message: format!("config {name_or_path} is a directory, not a YAML file"),
        });
    }
    if looks_like_path && path.exists() {
        // A FIFO, a socket or a device: refused before it is opened.
        nerf_files::bounded_read::check_regular_file(path, "config", MAX_YAML_BYTES as u64)
            .map_err(|e| ConfigError::unreadable(path, &e))?;
    }
    if !looks_like_path {
        let local = Path::new("configs").join(format!("{name_or_path}.yaml"));
        if local.is_file() {
            return Ok((read_config_file(&local)?, local.display().to_string()));
        }
        if let Some((_, text)) = BUILT_IN.iter().find(|(n, _)| *n == name_or_path) {
            return Ok(((*text).to_string(), format!("built-in {name_or_path}")));
        }
    }
    let message = match looks_like_path {
        true => format!("config file {name_or_path} not found"),
        false => {
            let known: Vec<&str> = BUILT_IN.iter().map(|(n, _)| *n).collect();
            format!("config `{name_or_path}` not found (not a file, not configs/{name_or_path}.yaml; built-in configs: {})", known.join(", "))
        }
    };
    Err(ConfigError::NotFound {
        name: name_or_path.to_string(),
        message,
    })
}

#[cfg(test)]
mod tests {
    use crate::test_box_with as box_with;
    use crate::Config;
    use nerf_field::sdf_config::SdfVolumeConfig;

    #[test]
    fn built_in_box_matches_the_homework() {
        let c = box_with(&[]).unwrap();
        assert_eq!(c.image_size(), (256, 256));
        assert_eq!(c.sampler.n_pts_per_ray, 64);
        assert_eq!((c.sampler.min_depth, c.sampler.max_depth), (0.0, 5.0));
        let s = c.implicit_function.get::<SdfVolumeConfig>().unwrap();
        assert_eq!(s.sdf.side_lengths.as_ref().unwrap().val, [1.75; 3]);
        assert_eq!(s.beta.val, 0.05);
        assert!(s.feature.rainbow);
        assert_eq!(c.cameras.radius, 3.0);
    }

    #[test]
    fn malformed_yaml_and_missing_configs() {
        assert!(
            format!("{:#}", Config::from_yaml("data: [1, 2", &[]).unwrap_err())
                .contains("malformed")
        );
        assert!(
            format!("{:#}", Config::load("no_such_config", &[]).unwrap_err()).contains("not found")
        );
    }
}
