//! Property tests (proptest) for the parsers that read user input: configs (YAML and
//! overrides), the dataset's transforms JSON, nerfstudio camera paths and the viewer's
//! `/render.png` query. Whatever the input, they return a value or an error; they never panic.

use std::path::Path;

use nerf::app::config::{apply_override, Config};
use nerf::app::view_request::{parse_view_query, ViewDefaults};
use nerf::io::camera_path::parse_camera_path;
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn camera_paths_never_panic(
        fov in prop_oneof![Just("50".to_string()), nasty_value()],
        size in prop_oneof![Just("64".to_string()), nasty_value()],
        fps in prop_oneof![Just("24".to_string()), nasty_value()],
        matrix in prop::collection::vec(prop_oneof![
            any::<f64>().prop_map(|v| format!("{v:e}")),
            Just("0".to_string()),
            Just("1".to_string()),
            Just("null".to_string()),
        ], 0..20),
        truncate in 0usize..400,
    ) {
        let json = format!(
            r#"{{"camera_type": "perspective", "render_width": {size}, "render_height": 32, "fps": {fps},
               "camera_path": [{{"camera_to_world": [{}], "fov": {fov}}}]}}"#,
            matrix.join(", ")
        );
        let _ = parse_camera_path(json.as_bytes());
        let cut = truncate.min(json.len());
        if json.is_char_boundary(cut) {
            let _ = parse_camera_path(&json.as_bytes()[..cut]);
        }
    }

    #[test]
    fn view_queries_never_panic(
        pairs in prop::collection::vec((
            prop_oneof![
                Just("eye".to_string()), Just("at".to_string()), Just("up".to_string()),
                Just("focal".to_string()), Just("width".to_string()), Just("height".to_string()),
                Just("client".to_string()), Just("gen".to_string()), "[ -~]{0,6}",
            ],
            prop_oneof![nasty_value(), Just("0,0,1".to_string()), "[-0-9.,e]{0,20}"],
        ), 0..6),
    ) {
        let defaults = ViewDefaults {
            eye: glam::DVec3::new(0.0, 0.0, -3.0),
            at: glam::DVec3::ZERO,
            up: glam::DVec3::Y,
            focal: 1.0,
            width: 8,
            height: 8,
        };
        if let Ok(request) = parse_view_query(&pairs, &defaults) {
            // Whatever passes is a usable camera and size.
            prop_assert!(request.camera.validate().is_ok());
            prop_assert!(request.width >= 1 && request.height >= 1);
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
