//! Integration tests that run the `nerf` binary as a user would.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn nerf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nerf"))
        .args(args)
        .output()
        .expect("run nerf")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn read_npy(path: &Path) -> (Vec<u64>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    let npy = npyz::NpyFile::new(&bytes[..]).unwrap();
    let shape = npy.shape().to_vec();
    (shape, npy.into_vec::<f32>().unwrap())
}

fn gif_frames(path: &Path) -> Vec<Vec<u8>> {
    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let mut decoder = options
        .read_info(std::fs::File::open(path).unwrap())
        .unwrap();
    let mut frames = Vec::new();
    while let Some(frame) = decoder.read_next_frame().unwrap() {
        frames.push(frame.buffer.to_vec());
    }
    frames
}

#[test]
fn render_box_writes_every_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("imgs");
    let o = nerf(&[
        "render",
        "--config",
        "box",
        "--out-dir",
        out.to_str().unwrap(),
        "--raw",
        "data.image_size=[40,30]",
        "sampler.n_pts_per_ray=32",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for name in ["grid_vis.png", "ray_vis.png", "point_vis.png", "depth.png"] {
        let img = image::open(out.join(name)).unwrap();
        let expected = if name == "point_vis.png" {
            (256, 256)
        } else {
            (40, 30)
        };
        assert_eq!((img.width(), img.height()), expected, "{name}");
    }
    assert_eq!(gif_frames(&out.join("render_cube.gif")).len(), 20);
    let (shape, color) = read_npy(&out.join("color_000.npy"));
    assert_eq!(shape, vec![30, 40, 3]);
    assert!(color
        .iter()
        .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    let (shape, depth) = read_npy(&out.join("depth_019.npy"));
    assert_eq!(shape, vec![30, 40]);
    assert!(depth
        .iter()
        .all(|v| v.is_finite() && *v >= 0.0 && *v <= 5.0));
    // The box is in the middle of the view: the central pixel is nearer than 3 and opaque.
    let centre = 15 * 40 + 20;
    assert!(depth[centre] > 1.5 && depth[centre] < 3.0);
    // Nothing temporary is left behind.
    assert!(std::fs::read_dir(&out).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(".tmp")));
}

#[test]
fn config_file_path_and_sphere_work() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("my.yaml");
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/sphere.yaml"))
        .unwrap();
    std::fs::write(&cfg, text).unwrap();
    let out = dir.path().join("o");
    let o = nerf(&[
        "render",
        "--config",
        cfg.to_str().unwrap(),
        "--out-dir",
        out.to_str().unwrap(),
        "data.image_size=[24,16]",
        "sampler.n_pts_per_ray=16",
        "cameras.n_poses=3",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(gif_frames(&out.join("render_cube.gif")).len(), 3);
}

/// Each bad input: non-zero exit, one line on stderr that mentions `needle`, no panic, and
/// nothing written into the output directory.
fn assert_clean_failure(args: &[&str], needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out: PathBuf = dir.path().join("out");
    let mut all: Vec<&str> = vec!["render", "--out-dir", out.to_str().unwrap()];
    all.extend_from_slice(args);
    let o = nerf(&all);
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(
        err.contains(needle),
        "{args:?}: expected `{needle}` in: {err}"
    );
    assert!(
        !out.exists() || std::fs::read_dir(&out).unwrap().next().is_none(),
        "{args:?} wrote files"
    );
}

#[test]
fn bad_input_gives_one_clear_line() {
    assert_clean_failure(&["--config", "nope"], "config `nope` not found");
    assert_clean_failure(
        &["--config", "box", "sampler.n_pts_per_ray=0"],
        "sampler.n_pts_per_ray",
    );
    assert_clean_failure(
        &["--config", "box", "sampler.min_depth=-1"],
        "sampler.min_depth",
    );
    assert_clean_failure(
        &["--config", "box", "sampler.min_depth=9"],
        "sampler.min_depth",
    );
    assert_clean_failure(
        &["--config", "box", "data.image_size=[0,4]"],
        "data.image_size",
    );
    assert_clean_failure(
        &["--config", "box", "renderer.chunk_size=0"],
        "renderer.chunk_size",
    );
    assert_clean_failure(&["--config", "box", "sampler.typo=3"], "typo");
    assert_clean_failure(
        &["--config", "box", "sampler.n_pts_per_ray=many"],
        "sampler.n_pts_per_ray",
    );
    assert_clean_failure(
        &["--config", "box", "implicit_function.beta.val=.nan"],
        "implicit_function.beta.val",
    );
    assert_clean_failure(
        &["--config", "box", "cameras.focal_length=.inf"],
        "cameras.focal_length",
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.yaml");
    std::fs::write(&bad, "data: [1, 2\nsampler: {").unwrap();
    assert_clean_failure(&["--config", bad.to_str().unwrap()], "malformed YAML");
}

#[test]
fn unwritable_output_directory_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a_file");
    std::fs::write(&file, b"x").unwrap();
    let target = file.join("sub");
    let o = nerf(&[
        "render",
        "--config",
        "box",
        "--out-dir",
        target.to_str().unwrap(),
        "data.image_size=[8,8]",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("cannot create output directory"),
        "{}",
        stderr(&o)
    );
}

fn reference_dir() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/reference_images");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}

fn psnr_u8(a: &[u8], b: &[u8]) -> f64 {
    let mse = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / a.len() as f64;
    10.0 * (255.0f64.powi(2) / mse).log10()
}

fn rgb_of_rgba(v: &[u8]) -> Vec<u8> {
    v.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect()
}

#[test]
fn box_render_agrees_with_the_homework_reference_images() {
    let Some(reference) = reference_dir() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let o = nerf(&[
        "render",
        "--config",
        "box",
        "--out-dir",
        out.to_str().unwrap(),
        "--raw",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for name in ["grid_vis.png", "ray_vis.png"] {
        let ours = image::open(out.join(name)).unwrap().to_rgb8();
        let theirs = image::open(reference.join(name)).unwrap().to_rgb8();
        let max = ours
            .as_raw()
            .iter()
            .zip(theirs.as_raw())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(max <= 2, "{name}: max channel difference {max}");
    }
    let reference_frames = gif_frames(&reference.join("render_cube.gif"));
    let our_gif = gif_frames(&out.join("render_cube.gif"));
    assert_eq!(reference_frames.len(), 20);
    let (mut float_psnr, mut gif_psnr) = (0.0, 0.0);
    for (i, r) in reference_frames.iter().enumerate() {
        let r = rgb_of_rgba(r);
        let (_, color) = read_npy(&out.join(format!("color_{i:03}.npy")));
        let ours: Vec<u8> = color.iter().map(|&v| nerf::images::to_byte(v)).collect();
        float_psnr += psnr_u8(&ours, &r) / 20.0;
        gif_psnr += psnr_u8(&rgb_of_rgba(&our_gif[i]), &r) / 20.0;
    }
    eprintln!("render_cube vs reference GIF: frames {float_psnr:.2} dB, our GIF {gif_psnr:.2} dB");
    // The reference GIF's own palette limits the agreement to about 35 dB.
    assert!(float_psnr >= 34.5, "frames: {float_psnr:.2} dB");
    assert!(gif_psnr >= 33.0, "GIF: {gif_psnr:.2} dB");
    // Depth (viridis) matches the reference except at a few edge pixels.
    let ours = image::open(out.join("depth.png")).unwrap().to_rgb8();
    let theirs = image::open(reference.join("depth.png")).unwrap().to_rgb8();
    let close = ours
        .as_raw()
        .iter()
        .zip(theirs.as_raw())
        .filter(|(a, b)| a.abs_diff(**b) <= 2)
        .count();
    assert!(close as f64 / ours.as_raw().len() as f64 > 0.95);
}

#[test]
fn train_render_and_eval_a_tiny_nerf() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/lego");
    if !data.join("transforms_train.json").is_file() {
        eprintln!("skipping: lego data not found at {}", data.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let ckpt_dir = dir.path().join("ckpt");
    let model = [
        "implicit_function.n_hidden_neurons_xyz=16",
        "implicit_function.n_hidden_neurons_dir=8",
        "implicit_function.n_layers_xyz=3",
        "implicit_function.append_xyz=[2]",
        "sampler.n_pts_per_ray=8",
        "data.image_size=[8,8]",
    ];
    let mut args = vec!["train", "--config", "nerf_lego", "--out-dir"];
    let images = dir.path().join("images");
    args.push(images.to_str().unwrap());
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt_dir.display());
    args.extend([
        "training.num_epochs=1",
        "training.batch_size=16",
        "training.render_interval=1",
        &ckpt_arg,
    ]);
    args.extend(model);
    let o = nerf(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let ckpt = ckpt_dir.join("nerf_lego.safetensors");
    assert!(ckpt.is_file());
    assert_eq!(
        std::fs::read_to_string(ckpt_dir.join("nerf_lego.log.jsonl"))
            .unwrap()
            .lines()
            .count(),
        100
    );
    assert_eq!(
        gif_frames(&images.join("render_nerf_training.gif")).len(),
        20
    );

    let out = dir.path().join("render");
    let mut args = vec![
        "render",
        "--config",
        "lego",
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--out-dir",
        out.to_str().unwrap(),
    ];
    args.extend(model);
    let o = nerf(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(gif_frames(&out.join("render_nerf.gif")).len(), 20);

    let saved = dir.path().join("eval");
    let mut args = vec![
        "eval",
        "--config",
        "lego",
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--split",
        "test",
        "--limit",
        "3",
        "--json",
        "--save-images",
        saved.to_str().unwrap(),
    ];
    args.extend(model);
    let o = nerf(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["views"].as_array().unwrap().len(), 3);
    assert!(report["mean_psnr"].as_f64().unwrap().is_finite());
    assert!(saved.join("r_0.png").is_file());

    // A checkpoint of another width is refused, naming the tensor.
    let o = nerf(&[
        "render",
        "--config",
        "lego",
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--out-dir",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("mlp_xyz.mlp.0.0.weight"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn bad_checkpoints_and_missing_data_give_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    // A real checkpoint of the lego config, then a truncated copy and random bytes.
    let config = nerf::config::Config::load("lego", &[]).unwrap();
    let state = nerf::train::NerfState::seeded(
        nerf::train::nerf_config(&config).unwrap(),
        0,
        &candle_core::Device::Cpu,
    )
    .unwrap();
    let good = dir.path().join("good.safetensors");
    nerf::checkpoint::save(
        &good,
        &nerf::checkpoint::model_tensors(&state.varmap),
        Default::default(),
    )
    .unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let truncated = dir.path().join("truncated.safetensors");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let garbage = dir.path().join("garbage.safetensors");
    std::fs::write(
        &garbage,
        (0..4000u32)
            .map(|i| (i * 7919 % 251) as u8)
            .collect::<Vec<_>>(),
    )
    .unwrap();
    let missing = dir.path().join("missing.safetensors");
    for (ckpt, needle) in [
        (&missing, "not found"),
        (&truncated, "corrupt"),
        (&garbage, "corrupt"),
    ] {
        let c = ckpt.to_str().unwrap();
        assert_clean_failure(&["--config", "lego", "--checkpoint", c], needle);
    }
    let nowhere = dir.path().join("no_data");
    for cmd in ["train", "eval"] {
        let ckpt_dir = format!(
            "training.checkpoint_path={}",
            dir.path().join("ck").display()
        );
        let mut args = vec![
            cmd,
            "--config",
            if cmd == "train" { "nerf_lego" } else { "lego" },
            "--data-dir",
            nowhere.to_str().unwrap(),
        ];
        if cmd == "train" {
            args.push(&ckpt_dir);
        } else {
            args.extend(["--checkpoint", good.to_str().unwrap()]);
        }
        let o = nerf(&args);
        assert_eq!(o.status.code(), Some(1));
        let err = stderr(&o);
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(
            err.contains("download") && err.contains("scripts/download_lego.sh"),
            "{err}"
        );
    }
    assert!(
        !dir.path().join("ck").exists(),
        "train wrote a checkpoint directory without data"
    );
}

#[test]
fn shipped_checkpoint_renders_and_scores_on_test_views() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let data = root.join("../shared/data/lego");
    if !data.join("transforms_test.json").is_file() {
        eprintln!("skipping: lego data not found at {}", data.display());
        return;
    }
    let checkpoint = root.join("checkpoints/nerf_lego.safetensors");
    let ckpt = checkpoint.to_str().unwrap();
    let data_arg = data.to_str().unwrap();
    // With its occupancy grid and early termination (the lego config), and densely.
    let eval = |extra: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "eval",
            "--config",
            "lego",
            "--checkpoint",
            ckpt,
            "--data-dir",
            data_arg,
            "--limit",
            "3",
            "--json",
        ];
        args.extend(extra);
        let o = nerf(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let fast = eval(&[]);
    let psnr = fast["mean_psnr"].as_f64().unwrap();
    let evaluated = fast["evaluated_fraction"].as_f64().unwrap();
    eprintln!(
        "shipped checkpoint, 3 test views at 128x128: {psnr:.2} dB, field at {:.1}% of samples",
        100.0 * evaluated
    );
    // A regression guard, not the score (the README reports all 200 views: these three score
    // 25.7 dB with the shipped model); the grid must skip most samples.
    assert!(psnr > 24.0, "{psnr}");
    assert!(evaluated < 0.1, "{evaluated}");
    // The render command writes the GIF from the checkpoint alone (no dataset).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = nerf(&[
        "render",
        "--config",
        "lego",
        "--checkpoint",
        ckpt,
        "--out-dir",
        out.to_str().unwrap(),
        "data.image_size=[32,32]",
        "cameras.n_poses=4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = gif_frames(&out.join("render_nerf.gif"));
    assert_eq!(frames.len(), 4);
    // Not blank: the model is there.
    assert!(frames[0].iter().filter(|v| **v > 40).count() > 50);
}
