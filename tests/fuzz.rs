//! Property tests (proptest) for the parsers that read user files: configs (YAML and
//! overrides) and the dataset's transforms JSON. Whatever the input, they return a value or an
//! error; they never panic.

use std::path::Path;

use nerf::app::config::{apply_override, Config};
use nerf::io::dataset::parse_split;
use proptest::prelude::*;

/// The built-in configs' text, as seeds for mutation.
fn seeds() -> Vec<String> {
    ["box", "sphere", "lego", "nerf_lego", "nerf_lego_fast"]
        .iter()
        .map(|n| nerf::app::config::config_text(n).unwrap().0)
        .collect()
}

/// YAML scalars and fragments that stress parsers: huge, negative, special floats, wrong
/// types, nesting, unicode.
fn nasty_value() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("0".to_string()),
        Just("-1".to_string()),
        Just(".nan".to_string()),
        Just("-.inf".to_string()),
        Just("1e400".to_string()),
        Just("18446744073709551616".to_string()),
        Just("[]".to_string()),
        Just("[1, [2, 3]]".to_string()),
        Just("{a: 1}".to_string()),
        Just("null".to_string()),
        Just("~".to_string()),
        Just("'ü✓'".to_string()),
        Just("True".to_string()),
        any::<i64>().prop_map(|v| v.to_string()),
        any::<f64>().prop_map(|v| format!("{v:e}")),
        "[ -~]{0,12}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn arbitrary_text_never_panics(text in "(?s).{0,300}") {
        let _ = Config::from_yaml(&text, &[]);
    }

    #[test]
    fn mutated_configs_never_panic(
        seed in 0usize..5,
        line in 0usize..60,
        value in nasty_value(),
        cut in 0usize..2000,
    ) {
        let seeds = seeds();
        let text = &seeds[seed % seeds.len()];
        // Replace the value of one `key: value` line.
        let lines: Vec<&str> = text.lines().collect();
        let i = line % lines.len();
        let mut mutated: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        if let Some((key, _)) = lines[i].split_once(':') {
            mutated[i] = format!("{key}: {value}");
        }
        let mutated = mutated.join("\n");
        let _ = Config::from_yaml(&mutated, &[]);
        // And a truncated copy.
        let cut = cut.min(text.len());
        if text.is_char_boundary(cut) {
            let _ = Config::from_yaml(&text[..cut], &[]);
        }
    }

    #[test]
    fn overrides_never_panic(
        seed in 0usize..5,
        key in prop_oneof![
            Just("sampler.n_pts_per_ray".to_string()),
            Just("renderer.occupancy_grid.resolution".to_string()),
            Just("renderer.occupancy_grid".to_string()),
            Just("renderer.early_termination".to_string()),
            Just("implicit_function.append_xyz".to_string()),
            Just("implicit_function.sdf.side_lengths.val".to_string()),
            Just("cameras.up".to_string()),
            Just("training.batch_size".to_string()),
            Just("data".to_string()),
            "[a-z_.]{0,30}",
        ],
        value in nasty_value(),
    ) {
        let seeds = seeds();
        let text = &seeds[seed % seeds.len()];
        let _ = Config::from_yaml(text, &[format!("{key}={value}")]);
        let mut root: serde_yaml_ng::Value = serde_yaml_ng::from_str(text).unwrap();
        let _ = apply_override(&mut root, &format!("{key}{value}"));
    }

    #[test]
    fn transforms_json_never_panics(
        fov in prop_oneof![Just("0.69".to_string()), nasty_value()],
        matrix in prop::collection::vec(prop_oneof![
            any::<f64>().prop_map(|v| format!("{v:e}")),
            Just("0".to_string()),
            Just("1".to_string()),
            Just("null".to_string()),
            Just("\"x\"".to_string()),
        ], 0..20),
        path in "[ -~]{0,20}",
        truncate in 0usize..400,
    ) {
        let rows: Vec<String> = matrix.chunks(4).map(|r| format!("[{}]", r.join(", "))).collect();
        let json = format!(
            r#"{{"camera_angle_x": {fov}, "frames": [{{"file_path": {path:?}, "rotation": 0.1, "transform_matrix": [{}]}}]}}"#,
            rows.join(", ")
        );
        let origin = Path::new("transforms_test.json");
        let _ = parse_split(json.as_bytes(), Path::new("data"), origin);
        let cut = truncate.min(json.len());
        if json.is_char_boundary(cut) {
            let _ = parse_split(&json.as_bytes()[..cut], Path::new("data"), origin);
        }
    }
}

#[test]
fn a_valid_transforms_file_parses() {
    // The identity-rotation camera 4 units up the z axis: a regression check that the fuzzed
    // parser accepts the real format.
    let json = r#"{"camera_angle_x": 0.6911112070083618, "frames": [{"file_path": "./test/r_0",
        "rotation": 0.0, "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}"#;
    let frames = parse_split(json.as_bytes(), Path::new("d"), Path::new("t.json")).unwrap();
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].file_path, Path::new("d/test/r_0.png"));
}
