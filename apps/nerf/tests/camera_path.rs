//! `nerf render --camera-path`: nerfstudio camera paths written by hand, whose poses are known.

use std::path::Path;

mod common;
use common::{max_byte_difference, nerf, nerf_ok, read_npy, render_args, stderr};

/// A path of `poses` (row-major OpenGL camera-to-world matrices) at `fov` degrees.
fn write_path(path: &Path, poses: &[[f64; 16]], fov: f64, (w, h): (usize, usize)) {
    let cameras: Vec<serde_json::Value> = poses
        .iter()
        .map(|m| serde_json::json!({"camera_to_world": m, "fov": fov, "aspect": w as f64 / h as f64}))
        .collect();
    let doc = serde_json::json!({
        "camera_type": "perspective", "render_width": w, "render_height": h,
        "fps": 10, "seconds": poses.len() as f64 / 10.0, "camera_path": cameras,
    });
    std::fs::write(path, serde_json::to_string_pretty(&doc).unwrap()).unwrap();
}

/// `nerf render` of the box config along the camera path in `json`, into `out`.
fn render_path_args<'a>(json: &'a Path, out: &'a Path) -> Vec<&'a str> {
    render_args("box", out, &["--camera-path", json.to_str().unwrap()])
}

/// The box config's surround camera 0 — eye (0, 0, −3) looking at the origin, +Y up, NDC focal
/// 1 — in OpenGL axes: right = −X, up = +Y, back = −Z; focal 1 is a 90° field of view.
const SURROUND_0: [f64; 16] = [
    -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, -3.0, 0.0, 0.0, 0.0, 1.0,
];

#[test]
fn a_path_through_a_surround_pose_renders_that_surround_frame() {
    let (dir, json) = common::scratch("path.json");
    // The second pose: the same camera moved to (0, 0, −4), so the box looks smaller.
    let mut farther = SURROUND_0;
    farther[11] = -4.0;
    write_path(&json, &[SURROUND_0, farther], 90.0, (40, 40));
    let out = dir.path().join("path");
    let small = ["sampler.n_pts_per_ray=32", "data.image_size=[40,40]"];
    nerf_ok(&[render_path_args(&json, &out).as_slice(), &small].concat());
    let raw = dir.path().join("raw");
    let mut args = render_args("box", &raw, &["--raw"]);
    args.extend(small);
    nerf_ok(&args);
    let (_, expected) = read_npy(&raw.join("color_000.npy"));
    let frame = image::open(out.join("frame_0000.png")).unwrap().to_rgb8();
    assert_eq!(frame.dimensions(), (40, 40));
    let worst = max_byte_difference(frame.as_raw(), &expected);
    // PNG bytes truncate like matplotlib: within one level.
    assert!(
        worst <= 1.0 / 255.0 + 1e-6,
        "frame 0 differs from surround frame 0 by {worst}"
    );
    // The farther camera sees less of the box: fewer bright pixels.
    let lit = |img: &image::RgbImage| img.pixels().filter(|p| p.0.iter().any(|c| *c > 20)).count();
    let far = image::open(out.join("frame_0001.png")).unwrap().to_rgb8();
    assert!(lit(&far) < lit(&frame), "{} vs {}", lit(&far), lit(&frame));
    let gif = std::fs::File::open(out.join("camera_path.gif")).unwrap();
    let mut decoder = gif::DecodeOptions::new().read_info(gif).unwrap();
    let mut n = 0;
    while let Some(f) = decoder.read_next_frame().unwrap() {
        assert_eq!(f.delay, 10, "10 fps is 10 hundredths a frame");
        n += 1;
    }
    assert_eq!(n, 2);
    // An MP4 comes only with ffmpeg.
    let has_ffmpeg = std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok();
    assert_eq!(out.join("camera_path.mp4").is_file(), has_ffmpeg);
}

#[test]
fn bad_camera_paths_fail_in_one_line() {
    let (dir, out) = common::scratch("out");
    let cases: Vec<(String, &str)> = vec![
        ("{\"render_width\": 8}".into(), "missing field"),
        ("not json".into(), "expected"),
        (
            serde_json::json!({"render_width": 8, "render_height": 8, "fps": 5,
                "camera_path": [{"camera_to_world": SURROUND_0, "fov": 0.0}]})
            .to_string(),
            "fov",
        ),
        (
            serde_json::json!({"render_width": 5000, "render_height": 8, "fps": 5,
                "camera_path": [{"camera_to_world": SURROUND_0, "fov": 50.0}]})
            .to_string(),
            "at most 4096",
        ),
    ];
    for (i, (text, expect)) in cases.iter().enumerate() {
        let json = dir.path().join(format!("bad{i}.json"));
        std::fs::write(&json, text).unwrap();
        let o = nerf(&render_path_args(&json, &out));
        let err = stderr(&o);
        assert!(!o.status.success(), "case {i} succeeded");
        assert_eq!(err.trim_end().lines().count(), 1, "case {i}: {err}");
        assert!(err.contains(expect), "case {i}: {err}");
        assert!(!out.exists(), "case {i} created the output directory");
    }
    let o = nerf(&render_path_args(Path::new("/nonexistent.json"), &out));
    assert!(!o.status.success() && stderr(&o).contains("cannot read camera path"));
}
