//! The homework's commands and configs through the binary: every config in
//! `../shared/homework/configs` runs as it is (`type` picks the job), the box is fitted by
//! gradient descent (`type: train`), and PyTorch checkpoints are read and written as the
//! homework keeps them. Each test works in its own temporary directory, which is the working
//! directory of the runs (the homework's paths are relative to it).

use std::path::{Path, PathBuf};

mod common;
use common::{homework_config, nerf_in, read_npy, render_args, stderr};

use candle_core::Device;
use nerf::config::Config;
use nerf::field::nerf::parameter_shapes;
use nerf::io::checkpoint::{self, CheckpointInfo};
use nerf::io::torch::{write_torch_checkpoint, TorchOptimizerInfo};
use nerf::NerfState;

/// The box the fit tests recover (not the homework's).
const TRUE_CENTER: &str = "implicit_function.sdf.center.val=[0.1,-0.15,0.05]";
const TRUE_SIDES: &str = "implicit_function.sdf.side_lengths.val=[1.8,1.3,1.6]";

fn fixtures() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tests/fixtures")
}

/// Asserts a run succeeded, printing its stderr otherwise.
fn ok(o: &std::process::Output, what: &str) -> String {
    assert!(o.status.success(), "{what}: {}", stderr(o));
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Asserts a clean failure: exit code 1, one line on stderr containing `needle`, no panic.
fn fails_with(o: &std::process::Output, needle: &str) {
    let err = common::one_line_error(o);
    assert!(err.contains(needle), "expected `{needle}` in: {err}");
}

/// Files in `dir` (none when it does not exist).
fn files_in(dir: &Path) -> Vec<String> {
    match std::fs::read_dir(dir) {
        Ok(entries) => entries
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect(),
        Err(_) => Vec::new(),
    }
}

/// Writes the targets of `config` (64x64) for the box of our choosing into `dir`.
fn make_targets(dir: &Path, config: &str) {
    let o = nerf_in(
        dir,
        &[
            "targets",
            "--config",
            config,
            TRUE_CENTER,
            TRUE_SIDES,
            "data.image_size=[64,64]",
        ],
    );
    let out = ok(&o, "nerf targets");
    assert_eq!(out.lines().count(), 4, "{out}");
    let (shape, values) = read_npy(&dir.join("data/box_0.npy"));
    assert_eq!(shape, vec![64, 64, 3]);
    assert!(values.iter().any(|v| *v > 0.1), "the target shows the box");
}

/// The fitted `[center, side_lengths]` from `sdf_fit.json`.
fn fitted(out: &Path) -> ([f64; 3], [f64; 3]) {
    let text = std::fs::read_to_string(out.join("sdf_fit.json")).unwrap();
    let j: serde_json::Value = serde_json::from_str(&text).unwrap();
    let v3 = |k: &str| -> [f64; 3] {
        let a = j["fitted"][k].as_array().unwrap();
        [0, 1, 2].map(|i| a[i].as_f64().unwrap())
    };
    (v3("center"), v3("side_lengths"))
}

#[test]
fn box_fit_recovers_a_box_of_our_choosing() {
    // From train_box's initial box (centre 0, sides 1.5) to centre (0.1, −0.15, 0.05), sides
    // (1.8, 1.3, 1.6): 64x64 targets (every pixel in each 4096-ray batch), 300 steps.
    let dir = tempfile::tempdir().unwrap();
    make_targets(dir.path(), "train_box");
    let start = std::time::Instant::now();
    let o = nerf_in(
        dir.path(),
        &[
            "train",
            "--config-name",
            "train_box",
            "data.image_size=[64,64]",
            "training.num_epochs=75",
            "training.lr=0.005",
        ],
    );
    let out = ok(&o, "nerf train --config train_box");
    eprintln!("fit in {:.1} s:\n{out}", start.elapsed().as_secs_f64());
    assert!(
        out.contains("Box center: (") && out.contains("Box side lengths: ("),
        "{out}"
    );
    let (center, sides) = fitted(&dir.path().join("images"));
    let (want_c, want_s) = ([0.1, -0.15, 0.05], [1.8, 1.3, 1.6]);
    for k in 0..3 {
        assert!((center[k] - want_c[k]).abs() < 0.01, "centre {center:?}");
        assert!((sides[k] - want_s[k]).abs() < 0.01, "sides {sides:?}");
    }
    let images = dir.path().join("images");
    for i in 0..4 {
        for stage in ["before", "after"] {
            let png = images.join(format!("render_box_{stage}_training_{i}.png"));
            let img = image::open(&png).unwrap();
            assert_eq!((img.width(), img.height()), (64, 64), "{}", png.display());
        }
    }
    assert!(images.join("render_box.gif").is_file());
    // The fitted box renders the target: the after image matches it to 8-bit precision.
    let after = image::open(images.join("render_box_after_training_0.png"))
        .unwrap()
        .to_rgb8();
    let (_, target) = read_npy(&dir.path().join("data/box_0.npy"));
    let worst = after
        .as_raw()
        .iter()
        .zip(&target)
        .map(|(a, t)| (*a as i32 - nerf::core::image::to_byte(*t) as i32).abs())
        .max()
        .unwrap();
    assert!(
        worst <= 1,
        "after-training image differs from the target by {worst}/255"
    );
}

#[test]
fn box_fit_refuses_bad_input_in_one_line_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let train = |extra: &[&str]| {
        let mut args = vec!["train", "--config", "train_box", "data.image_size=[64,64]"];
        args.extend_from_slice(extra);
        nerf_in(d, &args)
    };
    // No targets yet: the job names the file and how to make it.
    let o = train(&[]);
    fails_with(&o, "data.cameras.cam0.image");
    assert!(stderr(&o).contains("data/box_0.npy") && stderr(&o).contains("nerf targets"));
    make_targets(d, "train_box");
    // A wrong-shaped target, then an unreadable one.
    std::fs::copy(d.join("data/box_0.npy"), d.join("keep.npy")).unwrap();
    let small = nerf_in(
        d,
        &[
            "targets",
            "--config",
            "train_box",
            "data.image_size=[32,16]",
        ],
    );
    ok(&small, "small targets");
    fails_with(&train(&[]), "shape [16, 32, 3]");
    make_targets(d, "train_box");
    std::fs::write(d.join("data/box_2.npy"), b"not numpy").unwrap();
    fails_with(&train(&[]), "data.cameras.cam2.image");
    make_targets(d, "train_box");
    for (override_, needle) in [
        (
            "data.cameras.cam1.eye=[0.0,0.0,0.0]",
            "data.cameras.cam1.eye: equals scene_center",
        ),
        ("data.cameras={}", "data.cameras: missing"),
        (
            "implicit_function.sdf.radius={val: 1.0, opt: True}",
            "implicit_function.sdf.radius.opt: a box has no radius",
        ),
        ("data.cameras.cam3.focal=0", "data.cameras.cam3.focal"),
        ("training.num_epochs=0", "training.num_epochs"),
        ("training.lr=null", "training.lr: missing"),
    ] {
        fails_with(&train(&[override_]), needle);
    }
    let frozen = train(&[
        "implicit_function.sdf.center.opt=False",
        "implicit_function.sdf.side_lengths.opt=False",
    ]);
    fails_with(&frozen, "nothing to train");
    assert!(
        files_in(&d.join("images")).is_empty(),
        "a failed run wrote images"
    );
}

#[test]
fn commands_and_types_agree_or_name_the_command_to_use() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A render config cannot be trained; the error names the command.
    fails_with(
        &nerf_in(d, &["train", "--config", "box"]),
        "nerf render --config box",
    );
    fails_with(
        &nerf_in(d, &["train", "--config", "nerf_lego_render"]),
        "nerf render --config nerf_lego_render",
    );
    // eval scores a NeRF.
    fails_with(
        &nerf_in(d, &["eval", "--config", "train_box"]),
        "implicit_function.type",
    );
    // nerf render of the box fit's config renders its initial box (the sensible thing).
    let out = d.join("preview");
    let o = nerf_in(
        d,
        &[
            "render",
            "--config-name",
            "train_box",
            "--out-dir",
            out.to_str().unwrap(),
            "data.image_size=[24,24]",
            "sampler.n_pts_per_ray=16",
            "cameras.n_poses=2",
        ],
    );
    ok(&o, "render train_box");
    assert!(out.join("render_cube.gif").is_file());
    // nerf run dispatches on type: `render` renders.
    let o = nerf_in(
        d,
        &[
            "run",
            "--config",
            "sphere",
            "--out-dir",
            "run_out",
            "data.image_size=[24,24]",
            "cameras.n_poses=2",
        ],
    );
    ok(&o, "run sphere");
    assert!(d.join("run_out/render_cube.gif").is_file());
    // `type: train` fits (here with no targets, so it fails naming them), and a config
    // without a type is refused by run.
    fails_with(
        &nerf_in(d, &["run", "--config", "train_box"]),
        "data/box_0.npy",
    );
    fails_with(
        &nerf_in(d, &["run", "--config", "box", "type=null"]),
        "has no `type`",
    );
    fails_with(&nerf_in(d, &["run", "--config", "box", "type=fly"]), "type");
}

/// The homework's `nerf_lego_render.yaml` with a homework checkpoint file where its
/// `training.checkpoint_path` points (`./nerf_checkpoints`, a file, as `torch.load` reads
/// it): it renders with no change to the config, identically to the same weights from a
/// safetensors checkpoint. The overrides only shrink the work (16x16, 2 views, 16 points).
#[test]
fn nerf_lego_render_reads_a_pytorch_checkpoint_where_the_config_points() {
    let Some(config) = homework_config("nerf_lego_render") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The homework's NeRF (the sizes nerf_lego_render.yaml leaves out take their defaults).
    let params = Config::load(config.to_str().unwrap(), &[])
        .unwrap()
        .nerf_params()
        .unwrap();
    assert_eq!(
        (
            params.n_hidden_neurons_xyz,
            params.n_hidden_neurons_dir,
            params.n_layers_xyz
        ),
        (128, 64, 6)
    );
    assert_eq!(params.append_xyz, vec![3]);
    let state = NerfState::seeded(&params, 5, &Device::Cpu).unwrap();
    let tensors = checkpoint::model_tensors(&state.varmap);
    let info = CheckpointInfo {
        epoch: 7,
        ..Default::default()
    };
    let map = tensors.iter().cloned().collect();
    let optimizer = TorchOptimizerInfo {
        lr: 5e-4,
        initial_lr: 5e-4,
    };
    write_torch_checkpoint(
        &d.join("nerf_checkpoints"),
        &parameter_shapes(&params),
        &map,
        info.clone(),
        optimizer,
    )
    .unwrap();
    checkpoint::save(&d.join("same.safetensors"), &tensors, info).unwrap();
    let small = [
        "data.image_size=[16,16]",
        "cameras.n_poses=2",
        "sampler.n_pts_per_ray=16",
    ];
    let render = |out: &str, checkpoint: Option<&str>| {
        let mut args = render_args(config.to_str().unwrap(), out, &["--raw"]);
        if let Some(c) = checkpoint {
            args.extend(["--checkpoint", c]);
        }
        args.extend(small);
        ok(&nerf_in(d, &args), out);
    };
    render("from_pth", None);
    render("from_safetensors", Some("same.safetensors"));
    for i in 0..2 {
        let name = format!("color_{i:03}.npy");
        let (_, a) = read_npy(&d.join("from_pth").join(&name));
        let (_, b) = read_npy(&d.join("from_safetensors").join(&name));
        assert_eq!(a, b, "{name}");
    }
    assert!(d.join("from_pth/render_nerf.gif").is_file());
    // A directory holding the file works too; a missing one names the config's path.
    std::fs::create_dir(d.join("held")).unwrap();
    std::fs::rename(d.join("nerf_checkpoints"), d.join("held/model.pth")).unwrap();
    let mut args = render_args(
        config.to_str().unwrap(),
        "from_dir",
        &["training.checkpoint_path=held"],
    );
    args.extend(small);
    ok(&nerf_in(d, &args), "checkpoint directory");
    let o = nerf_in(d, &render_args(config.to_str().unwrap(), "none", &[]));
    fails_with(
        &o,
        "checkpoint ./nerf_checkpoints not found (training.checkpoint_path",
    );
    assert!(!d.join("none").exists());
}

#[test]
fn pytorch_made_checkpoint_renders_as_its_safetensors_twin() {
    // scripts/make_homework_checkpoint.py: the same tiny NeRF saved by torch.save in the
    // homework's {"model", "optimizer", "epoch"} form and as our safetensors.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let config = fixtures().join("tiny_nerf.yaml");
    let render = |name: &str| {
        let ckpt = fixtures().join(name);
        let more = [
            "--checkpoint",
            ckpt.to_str().unwrap(),
            "--raw",
            "data.image_size=[20,12]",
            "cameras.n_poses=3",
        ];
        let o = nerf_in(d, &render_args(config.to_str().unwrap(), name, &more));
        ok(&o, name);
        (0..3)
            .map(|i| read_npy(&d.join(name).join(format!("color_{i:03}.npy"))).1)
            .collect::<Vec<_>>()
    };
    let (a, b) = (
        render("tiny_nerf_homework.pth"),
        render("tiny_nerf_homework.safetensors"),
    );
    assert_eq!(a, b);
    assert!(
        a[0].iter().any(|v| *v > 0.05),
        "the model renders something"
    );
    // Both load with the same epoch, Adam step and moments.
    let params = Config::load(config.to_str().unwrap(), &[])
        .unwrap()
        .nerf_params()
        .unwrap();
    let load = |name: &str| {
        nerf::io::checkpoint_file::load(
            &fixtures().join(name),
            &parameter_shapes(&params),
            &Device::Cpu,
        )
        .unwrap()
    };
    let ((t1, i1), (t2, i2)) = (
        load("tiny_nerf_homework.pth"),
        load("tiny_nerf_homework.safetensors"),
    );
    assert_eq!((i1.epoch, i1.adam_step), (3, 3));
    assert_eq!((i1.epoch, i1.adam_step), (i2.epoch, i2.adam_step));
    assert_eq!(t1.len(), t2.len());
    for (name, t) in &t1 {
        let diff = nerf::core::compare::max_abs_difference(t, &t2[name]).unwrap();
        assert_eq!(diff, 0.0, "{name}");
    }
}

/// Training resumed from a homework PyTorch checkpoint continues its epoch, weights and Adam
/// state, and writes the checkpoint back in PyTorch's format.
#[test]
fn training_resumes_from_a_pytorch_checkpoint_and_keeps_its_format() {
    let Some((data, dir)) = common::lego_scratch() else {
        return;
    };
    let d = dir.path();
    let ckpt = d.join("checkpoint_file");
    std::fs::copy(fixtures().join("tiny_nerf_homework.pth"), &ckpt).unwrap();
    let config = fixtures().join("tiny_nerf.yaml");
    let o = nerf_in(
        d,
        &common::data_args(
            "train",
            config.to_str().unwrap(),
            &data,
            &[
                "training.checkpoint_path=checkpoint_file",
                "training.resume=True",
                "training.num_epochs=4",
                "training.batch_size=32",
                "training.lr=0.0005",
                "training.lr_scheduler_step_size=50",
                "training.lr_scheduler_gamma=0.8",
                "training.checkpoint_interval=1",
                "training.render_interval=100",
            ],
        ),
    );
    let out = ok(&o, "train from the PyTorch checkpoint");
    assert!(
        stderr(&o).contains("resuming from checkpoint_file at epoch 3"),
        "{}",
        stderr(&o)
    );
    assert!(out.contains("trained to epoch 4 (103 Adam steps"), "{out}");
    assert!(
        std::fs::read(&ckpt).unwrap().starts_with(b"PK\x03\x04"),
        "still a PyTorch file"
    );
    let params = Config::load(config.to_str().unwrap(), &[])
        .unwrap()
        .nerf_params()
        .unwrap();
    let torch = nerf::io::torch::read_torch_checkpoint(&ckpt, &parameter_shapes(&params)).unwrap();
    assert_eq!((torch.info.epoch, torch.info.adam_step), (4, 103));
    assert_eq!(torch.adam.len(), 2 * torch.model.len());
    let (before, _) = nerf::io::checkpoint_file::load(
        &fixtures().join("tiny_nerf_homework.pth"),
        &parameter_shapes(&params),
        &Device::Cpu,
    )
    .unwrap();
    let (name, trained) = &torch.model[0];
    let moved = nerf::core::compare::max_abs_difference(trained, &before[name]).unwrap();
    assert!(moved > 0.0, "training changed {name}");
}

/// Every config in `../shared/homework/configs`, read from there as it is. Overrides only
/// shrink the work (image size, epochs, samples) so that the test stays fast; the full-size
/// runs are in docs/homework.md.
#[test]
fn every_homework_config_runs_as_it_is() {
    let Some(box_yaml) = homework_config("box") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = |n: &str| homework_config(n).unwrap().to_str().unwrap().to_string();
    // box.yaml (type: render), exactly as it is: the homework's five outputs in images/.
    ok(
        &nerf_in(d, &["run", "--config", box_yaml.to_str().unwrap()]),
        "box.yaml",
    );
    for f in [
        "grid_vis.png",
        "ray_vis.png",
        "point_vis.png",
        "depth.png",
        "render_cube.gif",
    ] {
        assert!(d.join("images").join(f).is_file(), "{f}");
    }
    // train_box.yaml (type: train), with targets of our box at 64x64.
    let train_box = cfg("train_box");
    make_targets(d, &train_box);
    let o = nerf_in(
        d,
        &[
            "run",
            "--config",
            &train_box,
            "--out-dir",
            "fit",
            "data.image_size=[64,64]",
            "training.num_epochs=3",
        ],
    );
    let out = ok(&o, "train_box.yaml");
    assert!(out.contains("Box center:"), "{out}");
    assert!(d.join("fit/render_box_after_training_3.png").is_file());
    // nerf_lego.yaml and nerf_lego_highres.yaml (type: train_nerf): one small epoch each into
    // ./checkpoints, then `nerf render` of the training config renders that checkpoint.
    let Some(data) = common::lego_dir() else {
        return;
    };
    // Both keep ./checkpoints with resume: True, so the second continues the first.
    for (epochs, config) in [(1, "nerf_lego"), (2, "nerf_lego_highres")] {
        let path = cfg(config);
        let small = [
            "data.image_size=[16,16]",
            "sampler.n_pts_per_ray=8",
            "training.batch_size=64",
        ];
        let mut args = vec!["train", "--config", &path, "--epochs", "1", "--data-dir"];
        args.push(data.to_str().unwrap());
        args.extend(small);
        let out = ok(&nerf_in(d, &args), config);
        assert!(
            out.contains(&format!("trained to epoch {epochs} ")),
            "{out}"
        );
        assert!(d.join("checkpoints/nerf_lego.safetensors").is_file());
        let mut args = render_args(&path, config, &["cameras.n_poses=2"]);
        args.extend(small);
        ok(&nerf_in(d, &args), config);
        assert!(d.join(config).join("render_nerf.gif").is_file());
    }
}
