//! Trust under real use (issue 15), through the binary: output errors never panic, training
//! stops cleanly on a signal and resumes exactly, fresh runs never mix with old checkpoints,
//! and progress shows without a terminal.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{lego_dir, stderr};

/// A small box render (fast) into `out`.
fn box_render(out: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nerf"));
    c.args([
        "render",
        "--config",
        "box",
        "data.image_size=[24,24]",
        "cameras.n_poses=3",
        "--out-dir",
        out.to_str().unwrap(),
    ]);
    c
}

#[test]
fn closed_stdout_pipe_exits_quietly_without_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = box_render(&dir.path().join("o"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take()); // the reader goes away before anything is printed
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(141), "{err}");
    assert!(err.trim().is_empty(), "a closed pipe is quiet: {err}");
}

#[test]
fn full_disk_on_stdout_is_one_line_and_full_stderr_is_no_panic() {
    if !Path::new("/dev/full").exists() {
        use std::io::Write;
        let _ = writeln!(
            std::io::stderr(),
            "SKIPPED full-disk test: no /dev/full here"
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let full = || {
        std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap()
    };
    let out = box_render(&dir.path().join("a"))
        .stdout(full())
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("error: cannot write to stdout: No space left"),
        "{err}"
    );
    // A full stderr: the messages are lost, the job still runs and reports through its code.
    let out = box_render(&dir.path().join("b"))
        .stderr(full())
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(dir.path().join("b/render_cube.gif").is_file());
}

/// A tiny NeRF training run on the lego data (8×8 images; about 0.1 s per epoch).
fn tiny_train(ckpt_dir: &Path, data: &Path, epochs: usize) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nerf"));
    c.args([
        "train",
        "--config",
        "nerf_lego",
        "--data-dir",
        data.to_str().unwrap(),
        &format!("training.checkpoint_path={}", ckpt_dir.display()),
        &format!("training.num_epochs={epochs}"),
        "training.checkpoint_interval=5",
        "training.render_interval=1000",
        "training.batch_size=32",
        "training.lr=0.002",
        "implicit_function.n_hidden_neurons_xyz=16",
        "implicit_function.n_hidden_neurons_dir=8",
        "implicit_function.n_layers_xyz=3",
        "implicit_function.append_xyz=[2]",
        "sampler.n_pts_per_ray=8",
        "data.image_size=[8,8]",
        "--out-dir",
        ckpt_dir.join("images").to_str().unwrap(),
    ]);
    c.stdout(Stdio::null());
    c
}

fn log_lines(ckpt_dir: &Path) -> usize {
    std::fs::read_to_string(ckpt_dir.join("nerf_lego.log.jsonl")).map_or(0, |t| t.lines().count())
}

/// Sends `signal` to the child once its log holds at least `lines` lines.
fn signal_after(child: &std::process::Child, ckpt_dir: &Path, lines: usize, signal: i32) {
    let start = Instant::now();
    while log_lines(ckpt_dir) < lines {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "training made no progress"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    // SAFETY: kill only sends a signal to our own child process.
    unsafe { libc::kill(child.id() as i32, signal) };
}

fn load(
    ckpt_dir: &Path,
) -> (
    std::collections::HashMap<String, candle_core::Tensor>,
    nerf::CheckpointInfo,
) {
    nerf::io::checkpoint::load(
        &ckpt_dir.join("nerf_lego.safetensors"),
        &candle_core::Device::Cpu,
    )
    .unwrap()
}

#[test]
fn sigint_writes_a_checkpoint_mid_epoch_and_resume_is_exact() {
    let Some(data) = lego_dir("sigint_writes_a_checkpoint_mid_epoch_and_resume_is_exact") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let epochs = 4;
    let straight = dir.path().join("straight");
    assert!(tiny_train(&straight, &data, epochs)
        .status()
        .unwrap()
        .success());
    for (signal, name) in [(libc::SIGINT, "int"), (libc::SIGTERM, "term")] {
        let stopped = dir.path().join(name);
        let child = tiny_train(&stopped, &data, epochs)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Mid-epoch 1 (100 steps an epoch).
        signal_after(&child, &stopped, 150, signal);
        let out = child.wait_with_output().unwrap();
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(130), "{err}");
        assert!(err.contains("stopped at epoch 1 step"), "{err}");
        assert!(
            err.contains("resume with: nerf train --config nerf_lego"),
            "{err}"
        );
        let (_, info) = load(&stopped);
        assert!(info.step_in_epoch > 0 && info.epoch == 1, "{info:?}");
        // The log and the checkpoint agree about which steps exist.
        assert_eq!(log_lines(&stopped) as u64, info.adam_step);
        // Resume (the config resumes) and finish: the same model as the uninterrupted run.
        let out = tiny_train(&stopped, &data, epochs).output().unwrap();
        assert!(out.status.success(), "{}", stderr(&out));
        let ((a, ia), (b, ib)) = (load(&straight), load(&stopped));
        assert_eq!((ia.epoch, ia.adam_step), (ib.epoch, ib.adam_step));
        for (k, t) in &a {
            let d = common::max_abs_diff(
                &t.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                &b[k].flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            );
            assert_eq!(d, 0.0, "{name}: {k} differs by {d} after the resumed run");
        }
        assert_eq!(log_lines(&stopped), log_lines(&straight));
    }
}

#[test]
fn a_second_sigint_exits_at_once_and_leaves_whole_files() {
    let Some(data) = lego_dir("a_second_sigint_exits_at_once_and_leaves_whole_files") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("c");
    let child = tiny_train(&ckpt, &data, 50)
        .env("NERF_FAULT_WRITE_DELAY_MS", "300")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    signal_after(&child, &ckpt, 120, libc::SIGINT);
    std::thread::sleep(Duration::from_millis(20));
    // SAFETY: as above.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let start = Instant::now();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "{}", stderr(&out));
    assert!(start.elapsed() < Duration::from_secs(5));
    if ckpt.join("nerf_lego.safetensors").exists() {
        load(&ckpt); // whole, whichever write it was in
    }
}

#[test]
fn a_fresh_run_over_a_checkpoint_needs_overwrite_and_then_replaces_both_files() {
    let Some(data) =
        lego_dir("a_fresh_run_over_a_checkpoint_needs_overwrite_and_then_replaces_both_files")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("c");
    assert!(tiny_train(&ckpt, &data, 2).status().unwrap().success());
    assert_eq!(log_lines(&ckpt), 200);
    let before = std::fs::read(ckpt.join("nerf_lego.safetensors")).unwrap();
    let out = tiny_train(&ckpt, &data, 1)
        .arg("training.resume=False")
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(!out.status.success());
    assert!(
        err.contains("nerf_lego.safetensors already holds a checkpoint"),
        "{err}"
    );
    assert!(err.contains("--overwrite"), "{err}");
    assert_eq!(
        std::fs::read(ckpt.join("nerf_lego.safetensors")).unwrap(),
        before
    );
    assert_eq!(log_lines(&ckpt), 200, "the refused run left the log alone");
    let out = tiny_train(&ckpt, &data, 1)
        .args(["training.resume=False", "--overwrite"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let (_, info) = load(&ckpt);
    assert_eq!((info.epoch, info.adam_step), (1, 100));
    assert_eq!(
        log_lines(&ckpt),
        100,
        "log and checkpoint are the new run's"
    );
}

#[test]
fn training_without_a_terminal_prints_progress_lines() {
    let Some(data) = lego_dir("training_without_a_terminal_prints_progress_lines") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = tiny_train(&dir.path().join("c"), &data, 2)
        .env("NERF_PROGRESS_SECONDS", "0")
        .output()
        .unwrap();
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("step ")).collect();
    assert!(lines.len() >= 2, "{err}");
    assert!(lines
        .iter()
        .all(|l| l.contains("loss") && l.contains("psnr") && l.contains("eta")));
}

#[test]
fn eval_json_into_a_closed_pipe_exits_quietly() {
    // The case: `nerf eval --config lego --limit 1 --json | head -c0`.
    let Some(data) = lego_dir("eval_json_into_a_closed_pipe_exits_quietly") else {
        return;
    };
    let mut child = Command::new(env!("CARGO_BIN_EXE_nerf"))
        .args([
            "eval",
            "--config",
            "lego",
            "--limit",
            "1",
            "--json",
            "--data-dir",
        ])
        .arg(&data)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(141), "{err}");
}
