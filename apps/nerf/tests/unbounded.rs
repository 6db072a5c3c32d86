//! Unbounded captures and the views of a capture's model, through the binary: a nerfstudio
//! capture of the first 16 lego views trains with `nerf_scene_unbounded` (scene contraction,
//! depth-then-disparity sampling, the occupancy grid in contracted space), evaluates, and
//! `nerf render` / `nerf view` show it from the orbit stored in its checkpoint, which is the
//! one the training cameras give.

mod common;

use std::path::Path;

use nerf::io::checkpoint::{self, read_metadata};
use nerf::io::dataset::nerfstudio::NERFSTUDIO;
use nerf::io::dataset::{read_capture_split, CaptureOrbit, Split};

const FRAMES: usize = 16;

/// A nerfstudio capture (`transforms.json`, OPENCV without distortion, `images/` copies of
/// the PNGs) of the first [`FRAMES`] lego training views, in `dir`.
fn write_capture(lego: &Path, dir: &Path) {
    let text = std::fs::read_to_string(lego.join("transforms_train.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let fov = json["camera_angle_x"].as_f64().unwrap();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let frames: Vec<serde_json::Value> = json["frames"].as_array().unwrap()[..FRAMES]
        .iter()
        .map(|f| {
            let stem = f["file_path"].as_str().unwrap().rsplit('/').next().unwrap();
            let name = format!("images/{stem}.png");
            std::fs::copy(
                lego.join("train").join(format!("{stem}.png")),
                dir.join(&name),
            )
            .unwrap();
            serde_json::json!({"file_path": name, "transform_matrix": f["transform_matrix"]})
        })
        .collect();
    let (w, h) = image::image_dimensions(lego.join("train/r_0.png")).unwrap();
    let focal = 0.5 * w as f64 / (0.5 * fov).tan();
    let capture = serde_json::json!({
        "camera_model": "OPENCV", "fl_x": focal, "fl_y": focal,
        "cx": w as f64 / 2.0, "cy": h as f64 / 2.0, "w": w, "h": h, "frames": frames,
    });
    std::fs::write(dir.join("transforms.json"), capture.to_string()).unwrap();
}

#[test]
fn an_unbounded_capture_trains_evaluates_and_renders_and_views_from_its_orbit() {
    let Some(lego) = common::lego_dir() else {
        return;
    };
    let root = tempfile::tempdir().unwrap();
    let capture = root.path().join("capture");
    write_capture(&lego, &capture);
    let ckpt = root.path().join("unbounded.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    let overrides = [
        "data.image_size=[24,24]",
        "training.eval_views=0",
        "sampler.n_pts_per_ray=32",
        "sampler.n_pts_far=8",
        "cameras.n_poses=4",
        &ckpt_arg,
    ];
    let dir_arg = capture.to_str().unwrap();
    let config = ["--config", "nerf_scene_unbounded"];
    let with = |head: &[&'static str]| -> Vec<String> {
        head.iter()
            .chain(&config)
            .map(|s| s.to_string())
            .chain(overrides.iter().map(|s| s.to_string()))
            .collect()
    };
    let run = |args: Vec<String>| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        common::nerf_ok(&args)
    };
    let mut train = with(&["train", "--epochs", "2"]);
    train.extend(["--data-dir".to_string(), dir_arg.to_string()]);
    let log = common::stderr(&run(train));
    assert!(
        log.contains("nerfstudio") && log.contains("normalised"),
        "{log}"
    );

    // The checkpoint stores the orbit the training cameras give, exactly.
    let train_frames = read_capture_split(&capture, NERFSTUDIO, Split::Train)
        .unwrap()
        .frames;
    let expected = CaptureOrbit::from_frames(&train_frames).unwrap();
    let stored = checkpoint::CAPTURE_ORBIT
        .read(&read_metadata(&ckpt).unwrap(), &ckpt)
        .unwrap();
    assert_eq!(stored, Some(expected));
    // Lego's views stand on a sphere: the orbit lies inside the normalised frame's unit ball.
    assert!(
        expected.radius.hypot(expected.height) <= 1.0 + 1e-9,
        "{expected:?}"
    );

    let mut eval = with(&["eval", "--split", "test"]);
    eval.extend(["--data-dir".to_string(), dir_arg.to_string()]);
    let out = String::from_utf8_lossy(&run(eval).stdout).to_string();
    assert!(out.contains("PSNR") && out.contains("40 points"), "{out}");

    // render: the four orbit views, named on stderr, and something of lego in them.
    let images = root.path().join("render");
    let mut render = with(&["render", "--raw"]);
    render.extend(["--out-dir".to_string(), images.display().to_string()]);
    let log = common::stderr(&run(render));
    assert!(log.contains("4 views on the capture's orbit"), "{log}");
    assert!(images.join("render_nerf.gif").is_file());
    let npys: Vec<String> = common::sorted_names(&images)
        .into_iter()
        .filter(|n| n.ends_with(".npy") && n.contains("color"))
        .collect();
    assert_eq!(npys.len(), 4, "{npys:?}");
    for name in &npys {
        let (_, values) = common::read_npy(&images.join(name));
        let mean = values.iter().sum::<f32>() / values.len() as f32;
        assert!(mean.is_finite() && mean > 0.0, "{name}: {mean}");
    }

    // view: its default camera is the first orbit view, +z up, with the orbit's focal length.
    let mut args = config.to_vec();
    args.extend(overrides);
    let info = common::view_info(&args);
    let eye = expected.cameras(4)[0].center();
    let got: Vec<f64> = info["eye"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for k in 0..3 {
        assert!((got[k] - eye[k]).abs() < 1e-9, "{got:?} vs {eye}");
    }
    assert_eq!(info["up"], serde_json::json!([0.0, 0.0, 1.0]));
    assert_eq!(info["focal"].as_f64().unwrap(), expected.focal[0]);
}
