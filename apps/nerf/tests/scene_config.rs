//! `nerf_scene` on a capture with nothing set: photos of lego on a white backdrop without
//! alpha train at their own size under a time budget that outlasts `num_epochs`, the backdrop
//! colour and training size are stored in the checkpoint, and `eval` scores and writes the
//! photos' own size under their names on the stored background; a pixel budget scales large
//! photos down by a whole factor.

mod common;

use std::path::{Path, PathBuf};

use common::lego_capture::{lego_root, LegoRoot};
use tempfile::TempDir;

const SIDE: u32 = 40;

/// A nerfstudio capture of the first 16 lego views as `SIDE`² JPEGs composited on white (no
/// alpha), with the true cameras, in `name` of a fresh scratch directory: the directory and
/// the capture, or a visible skip.
fn white_capture(name: &str) -> Option<(TempDir, PathBuf)> {
    capture_on(name, |_, _| [1.0; 3])
}

/// [`white_capture`] with the views composited on `backdrop(x, y)` (RGB in [0, 1]).
fn capture_on(name: &str, backdrop: fn(u32, u32) -> [f32; 3]) -> Option<(TempDir, PathBuf)> {
    let LegoRoot { lego, root } = lego_root(16)?;
    let dir = root.path().join(name);
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let scale = SIDE as f64 / lego.size.0 as f64;
    let frames: Vec<serde_json::Value> = lego
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let rgba = image::open(&v.image).unwrap().to_rgba8();
            let small =
                image::imageops::resize(&rgba, SIDE, SIDE, image::imageops::FilterType::Triangle);
            let on_white = image::RgbImage::from_fn(SIDE, SIDE, |x, y| {
                let [r, g, b, a] = small.get_pixel(x, y).0.map(|c| c as f32 / 255.0);
                let [br, bg, bb] = backdrop(x, y);
                let over = |c: f32, back: f32| ((c * a + back * (1.0 - a)) * 255.0).round() as u8;
                image::Rgb([over(r, br), over(g, bg), over(b, bb)])
            });
            let name = format!("images/frame_{i:02}.jpg");
            on_white.save(dir.join(&name)).unwrap();
            serde_json::json!({"file_path": name, "transform_matrix": v.c2w})
        })
        .collect();
    let f = lego.focal_px() * scale;
    let json = serde_json::json!({
        "camera_model": "OPENCV", "fl_x": f, "fl_y": f, "cx": SIDE as f64 / 2.0,
        "cy": SIDE as f64 / 2.0, "w": SIDE, "h": SIDE, "frames": frames,
    });
    std::fs::write(dir.join("transforms.json"), json.to_string()).unwrap();
    Some((root, dir))
}

/// The overrides of a short training: one epoch of 32 samples a ray, nothing held out scored.
const ONE_EPOCH: [&str; 3] = [
    "training.num_epochs=1",
    "training.eval_views=0",
    "sampler.n_pts_per_ray=32",
];

fn metadata(path: &Path, key: &str) -> Option<String> {
    nerf::io::checkpoint::read_metadata(path)
        .unwrap()
        .get(key)
        .cloned()
}

#[test]
fn a_white_backdrop_capture_trains_for_its_time_at_its_size_and_scores_on_white() {
    let Some((root, data)) = white_capture("white") else {
        return;
    };
    let ckpt = root.path().join("ck").join("scene.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    // One epoch is 14 steps of about 20 ms on an idle 2-core machine: the time budget, not
    // num_epochs, must end the run.
    let mut args = common::data_args("train", "nerf_scene", &data, &["--minutes", "0.4"]);
    args.extend(ONE_EPOCH);
    args.push(&ckpt_arg);
    let train = common::nerf_ok(&args);
    let err = common::stderr(&train);
    assert!(err.contains("background white"), "{err}");
    // On a backdrop the camera clearance is kept.
    assert!(
        err.contains("kept empty around the 14 training cameras"),
        "{err}"
    );
    assert_eq!(metadata(&ckpt, "background").as_deref(), Some("1 1 1"));
    assert_eq!(metadata(&ckpt, "image_size").as_deref(), Some("40 40"));
    let epochs: usize = metadata(&ckpt, "epoch").unwrap().parse().unwrap();
    assert!(epochs >= 2, "the time budget stopped at epoch {epochs}");

    let renders = root.path().join("renders");
    let ckpt_path = ckpt.to_str().unwrap();
    let eval_with = |extra: &[&str]| {
        let head = common::data_args("eval", "nerf_scene", &data, &[]);
        let tail = [
            "--checkpoint",
            ckpt_path,
            "--split",
            "test",
            "sampler.n_pts_per_ray=32",
        ];
        common::nerf_ok(&[&head[..], &tail[..], extra].concat())
    };
    let eval = eval_with(&["--save-images", renders.to_str().unwrap()]);
    let out = String::from_utf8_lossy(&eval.stdout);
    assert!(
        out.contains("2 views at 40x40") && out.contains("on white"),
        "{out}"
    );
    // Every 8th photo is held out, written under its own name at its own size.
    assert_eq!(
        common::sorted_names(&renders),
        ["frame_00.png", "frame_08.png"]
    );
    let written = image::image_dimensions(renders.join("frame_08.png")).unwrap();
    assert_eq!(written, (SIDE, SIDE));
    // Told otherwise, eval renders on black.
    let black = eval_with(&["renderer.background=black"]);
    assert!(String::from_utf8_lossy(&black.stdout).contains("on black"));
}

#[test]
fn a_capture_without_a_backdrop_trains_without_camera_clearance_and_with_its_own_decay() {
    // A busy surround: a colour pattern no border reads as one plain backdrop.
    let busy = |x: u32, y: u32| {
        let v = |k: u32| ((x * 7 + y * 13 + k * 5) % 11) as f32 / 10.0;
        [v(0), v(1), v(2)]
    };
    let Some((root, data)) = capture_on("busy", busy) else {
        return;
    };
    let train = |extra: &[&str]| {
        let ckpt = root.path().join(format!("ck{}", extra.len()));
        let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
        let mut args = common::data_args("train", "nerf_scene", &data, &ONE_EPOCH);
        args.push(&ckpt_arg);
        common::stderr(&common::nerf_ok(&[&args[..], extra].concat()))
    };
    let err = train(&[]);
    assert!(err.contains("no plain backdrop"), "{err}");
    assert!(err.contains("no camera clearance"), "{err}");
    assert!(err.contains("occupancy-grid decay 0.9"), "{err}");
    assert!(!err.contains("kept empty around"), "{err}");
    // A background given explicitly keeps the configured clearance and decay.
    let err = train(&["renderer.background=black"]);
    assert!(!err.contains("occupancy-grid decay"), "{err}");
    assert!(
        err.contains("kept empty around the 14 training cameras"),
        "{err}"
    );
}

#[test]
fn a_pixel_budget_scales_the_photos_by_a_whole_factor_and_bad_values_are_named() {
    let Some((root, data)) = white_capture("white") else {
        return;
    };
    let ckpt = root.path().join("scene.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    let train = |extra: &str| {
        let mut args = common::data_args("train", "nerf_scene", &data, &ONE_EPOCH);
        args.extend([ckpt_arg.as_str(), extra]);
        common::nerf(&args)
    };
    // 40 × 40 = 1600 pixels over a budget of 400: half size, 20 × 20.
    let o = train("data.pixel_budget=400");
    assert!(o.status.success(), "{}", common::stderr(&o));
    assert_eq!(metadata(&ckpt, "image_size").as_deref(), Some("20 20"));
    let line = common::one_line_error(&train("data.pixel_budget=0"));
    assert!(line.contains("data.pixel_budget"), "{line}");
    let line = common::one_line_error(&train("renderer.background=pink"));
    assert!(line.contains("renderer.background"), "{line}");
}
