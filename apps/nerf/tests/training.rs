//! Training through the binary: a tiny NeRF trained, rendered and scored, a killed run resumed
//! exactly, held-out PSNR logged at checkpoints, and where `train` and `run` write checkpoints.

mod common;

use std::path::Path;

use common::{gif_frames, nerf, nerf_ok, render_args, stderr};

#[test]
fn train_render_and_eval_a_tiny_nerf() {
    let Some((_lego, dir)) = common::lego_scratch() else {
        return;
    };
    let ckpt_dir = dir.path().join("ckpt");
    let model = common::TINY_NERF_MODEL;
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
    nerf_ok(&args);
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
    let from_ckpt = ["--checkpoint", ckpt.to_str().unwrap()];
    let mut args = render_args("lego", &out, &from_ckpt);
    args.extend(model);
    nerf_ok(&args);
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
    let o = nerf_ok(&args);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["views"].as_array().unwrap().len(), 3);
    assert!(report["mean_psnr"].as_f64().unwrap().is_finite());
    // SSIM's 11×11 window does not fit these tiny images: reported as null, not an error.
    assert!(report["mean_ssim"].is_null() && report["views"][0]["ssim"].is_null());
    assert!(saved.join("r_0.png").is_file());

    // A checkpoint of another width is refused, naming the tensor.
    let o = nerf(&render_args("lego", &out, &from_ckpt));
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("mlp_xyz.mlp.0.0.weight"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn killed_training_leaves_a_whole_checkpoint_and_resumes_exactly() {
    // A checkpoint after each epoch: kills land anywhere, writes included.
    let epochs = 30;
    let Some((data, dir, straight)) = common::lego_trained("straight", epochs, 1) else {
        return;
    };
    let (_, straight_info) = common::load_trained(&straight);
    let steps_per_epoch = straight_info.adam_step / epochs as u64;
    let killed = dir.path().join("killed");
    let ckpt = killed.join("nerf_lego.safetensors");
    let log = killed.join("nerf_lego.log.jsonl");
    // Kills are placed by the run's progress, read from its log, not by wall time: on a busy
    // machine the same delay covers anything from loading the data to the whole run, and a
    // run that finishes before its kill ends the test with too few kills (seen in CI).
    let mut state = 12345u64;
    let mut last_epoch = 0;
    let (mut kills, mut mid_write) = (0, 0);
    for round in 0..12 {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        if round % 3 == 2 {
            // Temporary files of an earlier killed write (the run removes them too, at start).
            for e in std::fs::read_dir(&killed).into_iter().flatten().flatten() {
                if e.file_name().to_string_lossy().ends_with(".tmp") {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        // The furthest step logged so far (a killed run's steps past its checkpoint included).
        let logged = last_logged_step(&log);
        // Each write pauses 150 ms before its rename, so many kills land mid-write.
        let mut child = common::tiny_train(&killed, &data, epochs, 1)
            .env("NERF_FAULT_WRITE_DELAY_MS", "150")
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        let waiting = |child: &mut std::process::Child| {
            start.elapsed() < std::time::Duration::from_secs(60)
                && child.try_wait().unwrap().is_none()
        };
        if round % 3 == 2 {
            // Wait for a write in progress (its temporary file): a kill surely lands mid-write.
            while waiting(&mut child)
                && !std::fs::read_dir(&killed).is_ok_and(|d| {
                    d.flatten()
                        .any(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
                })
            {
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        } else {
            // Round 0 kills while the data loads; the others after 1 or 2 more epochs of
            // steps, then up to 0.2 s more: mid-epoch, mid-write or between.
            let ahead = if round == 0 { 0 } else { 1 + (state >> 40) % 2 };
            while waiting(&mut child) && last_logged_step(&log) < logged + ahead * steps_per_epoch {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            std::thread::sleep(std::time::Duration::from_millis((state >> 33) % 200));
        }
        let finished = child.try_wait().unwrap().is_some();
        if !finished {
            child.kill().unwrap(); // SIGKILL: no cleanup runs
            kills += 1;
        }
        child.wait().unwrap();
        // A temporary file left behind means the kill interrupted a write.
        if std::fs::read_dir(&killed).is_ok_and(|d| {
            d.flatten()
                .any(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        }) {
            mid_write += 1;
        }
        if ckpt.exists() {
            // Always a whole checkpoint: it loads, and it never goes back in time.
            let (tensors, info) =
                nerf::io::checkpoint::load(&ckpt, &candle_core::Device::Cpu).unwrap();
            assert!(tensors.contains_key("mlp_xyz.mlp.0.0.weight"));
            assert!(
                info.epoch >= last_epoch && info.epoch <= epochs,
                "round {round}: {info:?}"
            );
            last_epoch = info.epoch;
            // The log never holds a step the checkpoint does not.
            let logged = last_logged_step(&log);
            assert!(
                logged <= info.adam_step,
                "round {round}: log at {logged}, {info:?}"
            );
        } else {
            assert_eq!(
                last_logged_step(&log),
                0,
                "round {round}: a log without a checkpoint"
            );
        }
        if finished {
            break;
        }
    }
    eprintln!(
        "{kills} killed runs ({mid_write} during a write) reached epoch {last_epoch} of {epochs}"
    );
    assert!(kills >= 3, "only {kills} runs were killed");
    assert!(mid_write >= 1, "no kill landed during a write");
    // Finish, then compare with the uninterrupted run.
    common::tiny_train_ok(&killed, &data, epochs, 1);
    let (a, ia) = common::load_trained(&straight);
    let (b, ib) = nerf::io::checkpoint::load(&ckpt, &candle_core::Device::Cpu).unwrap();
    assert_eq!((ia.epoch, ia.adam_step), (ib.epoch, ib.adam_step));
    assert_eq!(a.len(), b.len());
    let mut worst = 0f32;
    for (name, t) in &a {
        // Weights and the Adam moments alike.
        let d = nerf::core::compare::max_abs_difference(t, &b[name]).unwrap();
        worst = worst.max(d);
    }
    assert!(worst < 1e-5, "resumed run differs by {worst}");
    // The log has each step once, and no temporary files are left.
    assert!(log.is_file());
    assert_eq!(
        common::logged_steps(&killed),
        (1..=ib.adam_step).collect::<Vec<_>>()
    );
    let leftovers = common::temp_files(&killed);
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// The `step` of a training log's last whole line (steps only grow along the log); 0 when
/// there is none yet. Reads only the log's tail, since the test polls it while a run trains.
fn last_logged_step(log: &std::path::Path) -> u64 {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut file) = std::fs::File::open(log) else {
        return 0;
    };
    let len = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut tail = String::new();
    if file
        .seek(SeekFrom::Start(len.saturating_sub(1024)))
        .is_err()
        || file.read_to_string(&mut tail).is_err()
    {
        return 0;
    }
    // A line still being written has no newline yet.
    let whole = &tail[..tail.rfind('\n').unwrap_or(0)];
    whole
        .rsplit('\n')
        .next()
        .and_then(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .and_then(|v| v["step"].as_u64())
        .unwrap_or(0)
}

#[test]
fn training_logs_test_psnr_at_checkpoints() {
    let Some((data, dir)) = common::lego_scratch() else {
        return;
    };
    let status = common::tiny_train(dir.path(), &data, 2, 1)
        .arg("training.eval_views=3")
        .status()
        .unwrap();
    assert!(status.success());
    let log = std::fs::read_to_string(dir.path().join("nerf_lego.log.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let tests: Vec<&serde_json::Value> = lines
        .iter()
        .filter(|v| v.get("test_psnr").is_some())
        .collect();
    assert_eq!(tests.len(), 2, "{log}");
    for (k, t) in tests.iter().enumerate() {
        assert_eq!(t["epoch"].as_u64(), Some(k as u64 + 1));
        assert_eq!(t["step"].as_u64(), Some(100 * (k as u64 + 1)));
        assert_eq!(t["test_views"].as_u64(), Some(3));
        let psnr = t["test_psnr"].as_f64().unwrap();
        assert!(psnr.is_finite() && psnr > 5.0, "{psnr}");
    }
    // Training steps are still logged once each.
    let steps: Vec<u64> = lines
        .iter()
        .filter(|v| v.get("loss").is_some())
        .map(|v| v["step"].as_u64().unwrap())
        .collect();
    assert_eq!(steps, (1..=200).collect::<Vec<_>>());
}

/// `nerf run` takes the training options `nerf train` takes; for a config that renders, each
/// given is named in a one-line error, and nothing is written.
#[test]
fn run_takes_training_options_and_refuses_them_for_render_configs() {
    let (_dir, out) = common::scratch("out");
    for (config, flags, named) in [
        (
            "box",
            &["--epochs", "1"][..],
            "--epochs is for NeRF training",
        ),
        (
            "nerf_lego_render",
            &["--minutes", "1", "--data-dir", "x"][..],
            "--data-dir, --minutes are for NeRF training",
        ),
    ] {
        let mut args = vec![
            "run",
            "--config",
            config,
            "--out-dir",
            out.to_str().unwrap(),
        ];
        args.extend(flags);
        let o = nerf(&args);
        let err = common::one_line_error(&o);
        assert!(err.contains(named) && err.contains("renders"), "{err}");
        assert!(!out.exists());
    }
    // An SDF fit has no checkpoint and runs training.num_epochs: the NeRF options are refused.
    for cmd in ["run", "train"] {
        let o = nerf(&[
            cmd,
            "--config",
            "train_box",
            "--checkpoint",
            "x",
            "--epochs",
            "2",
        ]);
        let err = common::one_line_error(&o);
        assert!(
            err.contains("--checkpoint, --epochs are for NeRF training")
                && err.contains("training.num_epochs"),
            "{err}"
        );
    }
}

/// `nerf train --checkpoint P` is `training.checkpoint_path=P`: the same checkpoint, at the
/// same place; `nerf run --epochs` of a train_nerf config stops as `nerf train --epochs`
/// does; and `--checkpoint DIR` reads back what training wrote there.
#[test]
fn train_checkpoint_is_the_config_checkpoint_path() {
    let Some((data, dir)) = common::lego_scratch() else {
        return;
    };
    let train = |cmd: &str, place: &[&str]| {
        let images = dir.path().join("images");
        let more = ["--out-dir", images.to_str().unwrap(), "--epochs", "1"];
        let mut args = common::data_args(cmd, "nerf_lego", &data, &more);
        args.extend(place);
        args.extend(common::TINY_NERF_TRAINING);
        args.extend(common::TINY_NERF_MODEL);
        let o = nerf(&args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let by_flag = dir.path().join("by_flag");
    let by_override = dir.path().join("by_override");
    let file = dir.path().join("model.safetensors");
    let out = train("train", &["--checkpoint", by_flag.to_str().unwrap()]);
    assert!(out.contains("trained to epoch 1 "), "{out}");
    let key = format!("training.checkpoint_path={}", by_override.display());
    train("train", &[&key]);
    // The flag wins over an override given with it, as a later override would.
    let elsewhere = dir.path().join("elsewhere");
    let key_elsewhere = format!("training.checkpoint_path={}", elsewhere.display());
    train(
        "run",
        &["--checkpoint", file.to_str().unwrap(), &key_elsewhere],
    );
    assert!(!elsewhere.exists());
    let load = |p: &Path| nerf::io::checkpoint::load(p, &candle_core::Device::Cpu).unwrap();
    let (a, info_a) = load(&by_flag.join("nerf_lego.safetensors"));
    let (b, info_b) = load(&by_override.join("nerf_lego.safetensors"));
    let (c, info_c) = load(&file);
    assert!(
        by_flag.join("nerf_lego.log.jsonl").is_file() && file.with_extension("log.jsonl").is_file()
    );
    for (name, t) in &a {
        for other in [&b, &c] {
            let d = nerf::core::compare::max_abs_difference(t, &other[name]).unwrap();
            assert_eq!(d, 0.0, "{name}");
        }
    }
    for info in [&info_a, &info_b, &info_c] {
        assert_eq!((info.epoch, info.adam_step), (1, 100));
    }
    // Run again with the flag: it resumes from that checkpoint (resume: True in nerf_lego).
    let out = train("run", &["--checkpoint", by_flag.to_str().unwrap()]);
    assert!(out.contains("trained to epoch 2 "), "{out}");
    // A directory holding the checkpoint is what --checkpoint reads, too.
    let render = dir.path().join("render");
    let mut args = render_args(
        "nerf_lego",
        &render,
        &[
            "--checkpoint",
            by_flag.to_str().unwrap(),
            "cameras.n_poses=2",
        ],
    );
    args.extend(common::TINY_NERF_TRAINING);
    args.extend(common::TINY_NERF_MODEL);
    let o = nerf_ok(&args);
    assert!(stderr(&o).contains("epoch 2"), "{}", stderr(&o));
}
