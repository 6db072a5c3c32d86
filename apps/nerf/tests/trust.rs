//! Trust under real use (issue 15), through the binary: output errors never panic, training
//! stops cleanly on a signal and resumes exactly, fresh runs never mix with old checkpoints,
//! and progress shows without a terminal.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{lego_dir, lego_scratch, logged_steps, render_args, stderr, temp_files};

/// A small box render (fast) into `out`.
fn box_render(out: &Path) -> Command {
    let mut c = common::nerf_command();
    c.args(render_args(
        "box",
        out,
        &["data.image_size=[24,24]", "cameras.n_poses=3"],
    ));
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

/// [`common::tiny_train`] with a checkpoint every 5 epochs.
fn tiny_train(ckpt_dir: &Path, data: &Path, epochs: usize) -> Command {
    common::tiny_train(ckpt_dir, data, epochs, 5)
}

fn log_lines(ckpt_dir: &Path) -> usize {
    std::fs::read_to_string(ckpt_dir.join("nerf_lego.log.jsonl")).map_or(0, |t| t.lines().count())
}

/// A training run whose stderr is read as it comes: its progress lines (one per step) say
/// how far it is, since its log only grows when a checkpoint is written.
struct Watched {
    child: std::process::Child,
    step: std::sync::Arc<std::sync::atomic::AtomicU64>,
    stderr: std::thread::JoinHandle<String>,
}

fn watched(mut command: Command) -> Watched {
    use std::io::BufRead;
    let mut child = command
        .env("NERF_PROGRESS_SECONDS", "0")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pipe = child.stderr.take().unwrap();
    let step = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let seen = step.clone();
    let stderr = std::thread::spawn(move || {
        let mut text = String::new();
        for line in std::io::BufReader::new(pipe).lines().map_while(Result::ok) {
            // `step N (done/total this run): …`
            if let Some(n) = line
                .strip_prefix("step ")
                .and_then(|r| r.split(' ').next())
                .and_then(|n| n.parse().ok())
            {
                seen.store(n, std::sync::atomic::Ordering::SeqCst);
            }
            text += &line;
            text.push('\n');
        }
        text
    });
    Watched {
        child,
        step,
        stderr,
    }
}

impl Watched {
    /// Sends `signal` to the run once it has taken `steps` steps.
    fn signal_after(&self, steps: u64, signal: i32) {
        let start = Instant::now();
        while self.step.load(std::sync::atomic::Ordering::SeqCst) < steps {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "training made no progress"
            );
            std::thread::sleep(Duration::from_millis(2));
        }
        // SAFETY: kill only sends a signal to our own child process.
        unsafe { libc::kill(self.child.id() as i32, signal) };
    }

    /// The exit code and everything the run wrote on stderr.
    fn finish(mut self) -> (Option<i32>, String) {
        let status = self.child.wait().unwrap();
        (status.code(), self.stderr.join().unwrap())
    }
}

#[test]
fn sigint_writes_a_checkpoint_mid_epoch_and_resume_is_exact() {
    let epochs = 4;
    let Some((data, dir, straight)) = common::lego_trained("straight", epochs, 5) else {
        return;
    };
    for (signal, name) in [(libc::SIGINT, "int"), (libc::SIGTERM, "term")] {
        let stopped = dir.path().join(name);
        let run = watched(tiny_train(&stopped, &data, epochs));
        // Mid-epoch 1 (100 steps an epoch).
        run.signal_after(150, signal);
        let (code, err) = run.finish();
        assert_eq!(code, Some(130), "{err}");
        assert!(err.contains("stopped at epoch 1 step"), "{err}");
        assert!(
            err.contains("resume with: nerf train --config nerf_lego"),
            "{err}"
        );
        let (_, info) = common::load_trained(&stopped);
        assert!(info.step_in_epoch > 0 && info.epoch == 1, "{info:?}");
        // The log and the checkpoint agree about which steps exist.
        assert_eq!(log_lines(&stopped) as u64, info.adam_step);
        // Resume (the config resumes) and finish: the same model as the uninterrupted run.
        let out = tiny_train(&stopped, &data, epochs)
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", stderr(&out));
        let ((a, ia), (b, ib)) = (
            common::load_trained(&straight),
            common::load_trained(&stopped),
        );
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
    let Some((data, dir)) = lego_scratch() else {
        return;
    };
    let ckpt = dir.path().join("c");
    let mut command = tiny_train(&ckpt, &data, 50);
    command.env("NERF_FAULT_WRITE_DELAY_MS", "300");
    let run = watched(command);
    run.signal_after(120, libc::SIGINT);
    // The first interrupt's checkpoint is being written (its rename waits 300 ms).
    std::thread::sleep(Duration::from_millis(20));
    // SAFETY: as above.
    unsafe { libc::kill(run.child.id() as i32, libc::SIGINT) };
    let start = Instant::now();
    let (code, err) = run.finish();
    assert_eq!(code, Some(130), "{err}");
    assert!(start.elapsed() < Duration::from_secs(5));
    // No temporary file is left, and the log holds no step the checkpoint does not.
    assert!(temp_files(&ckpt).is_empty(), "{:?}", temp_files(&ckpt));
    let held = if ckpt.join("nerf_lego.safetensors").exists() {
        common::load_trained(&ckpt).1.adam_step // whole, whichever write it was in
    } else {
        0
    };
    assert!(
        logged_steps(&ckpt).iter().all(|&s| s <= held),
        "the log runs ahead of the checkpoint (step {held})"
    );
}

#[test]
fn a_fresh_run_over_a_checkpoint_needs_overwrite_and_then_replaces_both_files() {
    let Some((data, _dir, ckpt)) = common::lego_trained("c", 2, 5) else {
        return;
    };
    assert_eq!(log_lines(&ckpt), 200);
    let before = std::fs::read(ckpt.join("nerf_lego.safetensors")).unwrap();
    let out = tiny_train(&ckpt, &data, 1)
        .arg("training.resume=False")
        .stderr(Stdio::piped())
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
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    let (_, info) = common::load_trained(&ckpt);
    assert_eq!((info.epoch, info.adam_step), (1, 100));
    assert_eq!(
        log_lines(&ckpt),
        100,
        "log and checkpoint are the new run's"
    );
}

#[test]
fn training_without_a_terminal_prints_progress_lines() {
    let Some((data, dir)) = lego_scratch() else {
        return;
    };
    let out = tiny_train(&dir.path().join("c"), &data, 2)
        .env("NERF_PROGRESS_SECONDS", "0")
        .stderr(Stdio::piped())
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
    let Some(data) = lego_dir() else {
        return;
    };
    let mut child = common::nerf_command()
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
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
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

/// `nerf render --config nerf_lego ... --raw` at 16×16, 2 poses; stderr and frame 0's colour.
fn render_nerf(out: &Path, extra: &[&str]) -> (String, Vec<f32>) {
    let small = ["--raw", "data.image_size=[16,16]", "cameras.n_poses=2"];
    let mut args = render_args("nerf_lego", out, &small);
    args.extend(extra);
    let o = common::nerf_command()
        .args(&args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(o.status.success(), "{args:?}: {err}");
    (err, common::read_npy(&out.join("color_000.npy")).1)
}

#[test]
fn one_rule_picks_the_checkpoint_and_says_which() {
    let dir = tempfile::tempdir().unwrap();
    let info = |epoch| nerf::CheckpointInfo {
        epoch,
        adam_step: 7,
        ..Default::default()
    };
    // A directory holding nerf_lego.safetensors, and a file elsewhere, with other weights.
    let ckpt_dir = dir.path().join("mine");
    common::save_seeded_checkpoint_with(&ckpt_dir.join("nerf_lego.safetensors"), &[], 1, info(3));
    let file = dir.path().join("other.safetensors");
    common::save_seeded_checkpoint_with(&file, &[], 2, info(5));
    let dir_arg = format!("training.checkpoint_path={}", ckpt_dir.display());
    let file_arg = format!("training.checkpoint_path={}", file.display());
    // No --checkpoint: the config's checkpoint_path (nerf_lego's is checkpoints/homework).
    let (err, homework) = render_nerf(&dir.path().join("a"), &[]);
    assert!(
        err.contains("loaded ./checkpoints/homework/nerf_lego.safetensors"),
        "{err}"
    );
    // checkpoint_path as a directory, then as a file.
    let (err, from_dir) = render_nerf(&dir.path().join("b"), &[&dir_arg]);
    let expected = format!(
        "loaded {}/nerf_lego.safetensors (epoch 3, 7 Adam steps)",
        ckpt_dir.display()
    );
    assert!(err.contains(&expected), "{err}");
    let (err, from_file) = render_nerf(&dir.path().join("c"), &[&file_arg]);
    assert!(
        err.contains(&format!("loaded {} (epoch 5", file.display())),
        "{err}"
    );
    // --checkpoint wins over checkpoint_path.
    let file_str = file.to_str().unwrap();
    let (err, given) = render_nerf(&dir.path().join("d"), &[&dir_arg, "--checkpoint", file_str]);
    assert!(
        err.contains(&format!("loaded {} (epoch 5", file.display())),
        "{err}"
    );
    assert_eq!(given, from_file);
    assert!(
        common::max_abs_diff(&from_dir, &from_file) > 1e-3,
        "other weights, other render"
    );
    assert!(common::max_abs_diff(&from_dir, &homework) > 1e-3);
    // A config without a training section (lego): the shipped model.
    let e = dir.path().join("e");
    let o = common::nerf_command()
        .args(render_args(
            "lego",
            &e,
            &["data.image_size=[8,8]", "cameras.n_poses=1"],
        ))
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("loaded checkpoints/nerf_lego.safetensors (epoch 160"),
        "{err}"
    );
}

#[test]
fn eval_follows_the_same_rule_and_reads_only_the_frames_it_scores() {
    let dir = tempfile::tempdir().unwrap();
    let data = tiny_dataset(dir.path(), &[(8, 8, true), (8, 8, true), (8, 8, true)]);
    // The third frame's image is missing: --limit 2 never opens it.
    std::fs::remove_file(data.join("test/r_2.png")).unwrap();
    let ckpt_dir = dir.path().join("mine");
    common::save_seeded_checkpoint(&ckpt_dir.join("nerf_lego.safetensors"), &[]);
    let dir_arg = format!("training.checkpoint_path={}", ckpt_dir.display());
    let eval = |extra: &[&str]| {
        let mut c = common::nerf_command();
        c.args(["eval", "--config", "nerf_lego", "--data-dir"])
            .arg(&data)
            .args(["data.image_size=[8,8]", "sampler.n_pts_per_ray=8"])
            .args(extra);
        c.output().unwrap()
    };
    let o = eval(&["--limit", "2", &dir_arg]);
    let (err, out) = (stderr(&o), String::from_utf8_lossy(&o.stdout).to_string());
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains(&format!(
            "loaded {}/nerf_lego.safetensors",
            ckpt_dir.display()
        )),
        "{err}"
    );
    assert!(out.contains("test split, 2 views at 8x8"), "{out}");
    let o = eval(&["--limit", "1", &dir_arg]);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("1 view at"),
        "plural"
    );
    let o = eval(&[&dir_arg]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("r_2.png"), "{}", stderr(&o));
}

/// A NeRF-synthetic style test split of `sizes` (width, height, with alpha) in `root/data`:
/// cameras on a circle of radius 4 looking at the origin, PNGs of a flat colour.
fn tiny_dataset(root: &Path, sizes: &[(u32, u32, bool)]) -> std::path::PathBuf {
    let data = root.join("data");
    std::fs::create_dir_all(data.join("test")).unwrap();
    let mut frames = Vec::new();
    for (i, &(w, h, alpha)) in sizes.iter().enumerate() {
        let a = i as f64 * 0.7;
        let (c, s) = (a.cos(), a.sin());
        // Blender camera-to-world: the camera's +Z points away from the origin.
        let m = [
            [c, 0.0, s, 4.0 * s],
            [0.0, 1.0, 0.0, 0.0],
            [-s, 0.0, c, 4.0 * c],
            [0.0, 0.0, 0.0, 1.0],
        ];
        frames.push(format!(
            "{{\"file_path\": \"./test/r_{i}\", \"transform_matrix\": {m:?}}}"
        ));
        let path = data.join(format!("test/r_{i}.png"));
        if alpha {
            image::RgbaImage::from_pixel(w, h, image::Rgba([200, 100, 50, 255]))
                .save(&path)
                .unwrap();
        } else {
            image::RgbImage::from_pixel(w, h, image::Rgb([200, 100, 50]))
                .save(&path)
                .unwrap();
        }
    }
    std::fs::write(
        data.join("transforms_test.json"),
        format!(
            "{{\"camera_angle_x\": 0.69, \"frames\": [{}]}}",
            frames.join(",")
        ),
    )
    .unwrap();
    data
}

#[test]
fn frames_of_another_size_are_refused_and_missing_alpha_is_said() {
    let dir = tempfile::tempdir().unwrap();
    let data = tiny_dataset(dir.path(), &[(8, 8, true), (6, 4, true)]);
    let ckpt = dir.path().join("m.safetensors");
    common::save_seeded_checkpoint(&ckpt, &[]);
    let eval = |data: &Path| {
        common::nerf_command()
            .args(["eval", "--config", "nerf_lego", "--checkpoint"])
            .arg(&ckpt)
            .arg("--data-dir")
            .arg(data)
            .args(["data.image_size=[8,8]", "sampler.n_pts_per_ray=8"])
            .output()
            .unwrap()
    };
    let o = eval(&data);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("r_1.png is 6x4, but the split's images are 8x8"),
        "{err}"
    );
    let other = tempfile::tempdir().unwrap();
    let data = tiny_dataset(other.path(), &[(8, 8, true), (8, 8, false)]);
    let o = eval(&data);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("1 of the 2 images"), "{err}");
    assert!(
        err.contains("no alpha channel and are taken as opaque"),
        "{err}"
    );
}

fn fails_with(args: &[&str], needle: &str) {
    let o = common::nerf_command()
        .args(args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
    assert!(
        err.contains(needle),
        "{args:?}: expected `{needle}` in {err}"
    );
}

#[test]
fn messages_speak_the_users_language() {
    // The override is blamed, not the file; type names are in words.
    fails_with(
        &["render", "--config", "box", "sampler.n_pts_per_ray=abc"],
        "error: override `sampler.n_pts_per_ray=abc`: sampler.n_pts_per_ray: invalid type: string \"abc\", expected a whole number",
    );
    fails_with(
        &["render", "--config", "box", "sampler=3"],
        "expected a section of `key: value` lines",
    );
    fails_with(
        &["render", "--config", "/abs/dir/nope.yaml"],
        "error: config file /abs/dir/nope.yaml not found",
    );
    let (dir, bad) = common::scratch("bad.yaml");
    std::fs::write(
        &bad,
        "data:\n  image_size: [8, 8]\nrenderer:\n  chunk_size: 0\nsampler:\n  n_pts_per_ray: 4\n  min_depth: 0\n  max_depth: 1\nimplicit_function:\n  type: nerf\n",
    )
    .unwrap();
    fails_with(
        &["render", "--config", bad.to_str().unwrap()],
        &format!(
            "config {}, line 4: renderer.chunk_size: must be at least 1",
            bad.display()
        ),
    );
    fails_with(
        &["train", "--config", "lego"],
        "config lego has `type: render`: it renders, it does not train; run `nerf render --config lego` (or `nerf run --config lego`); to train this scene: `nerf train --config nerf_lego_fast`",
    );
    fails_with(
        &["eval", "--config", "box"],
        "this command needs a NeRF config (e.g. lego)",
    );
    // Hydra's +key=value adds a key.
    let out = dir.path().join("o");
    let o = common::nerf(&render_args(
        "box",
        &out,
        &["+cameras.n_poses=2", "data.image_size=[8,8]"],
    ));
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn every_subcommand_takes_config_the_same_way() {
    for cmd in ["render", "train", "eval", "import-torch", "bench"] {
        let o = common::nerf_command()
            .args([cmd, "--help"])
            .output()
            .unwrap();
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(
            help.contains("--config <CONFIG>")
                && help.contains("Config name (configs/NAME.yaml or built-in)"),
            "{cmd}: {help}"
        );
    }
    // None defaults to some config: leaving it out is a usage error.
    for cmd in [&["bench"][..], &["import-torch", "x.pth"][..]] {
        let o = common::nerf_command().args(cmd).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{cmd:?}");
        assert!(stderr(&o).contains("--config <CONFIG>"));
    }
}

#[test]
fn raw_frames_are_one_clean_set() {
    let (_dir, out) = common::scratch("o");
    let render = |poses: &str| {
        let o = common::nerf_command()
            .args([
                "render",
                "--config",
                "box",
                "--raw",
                "data.image_size=[8,8]",
            ])
            .arg(format!("cameras.n_poses={poses}"))
            .arg("--out-dir")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    };
    render("4");
    std::fs::write(out.join("color_notes.npy"), b"mine").unwrap();
    render("2");
    for i in 0..4 {
        let exists = out.join(format!("color_{i:03}.npy")).exists();
        assert_eq!(exists, i < 2, "color_{i:03}.npy");
        assert_eq!(out.join(format!("depth_{i:03}.npy")).exists(), i < 2);
    }
    assert!(
        out.join("color_notes.npy").exists(),
        "only our own frame files are removed"
    );
}

#[test]
fn pytorch_files_where_safetensors_go_and_damaged_archives_are_named() {
    let fixture = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("tests/fixtures/tiny_nerf.pth");
    let config = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("tests/fixtures/tiny_nerf.yaml");
    let dir = tempfile::tempdir().unwrap();
    // A .pth given as --checkpoint is read as it is (by its content): it renders with its own
    // config, and with another config's sizes the error names the tensor and both shapes.
    let render = |config: &Path, out: &str| {
        common::nerf_command()
            .args(["render", "--config"])
            .arg(config)
            .arg("--checkpoint")
            .arg(&fixture)
            .arg("--out-dir")
            .arg(dir.path().join(out))
            .output()
            .unwrap()
    };
    let o = render(Path::new("lego"), "o");
    let err = stderr(&o);
    assert!(!o.status.success());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains(
            "tensor mlp_xyz.mlp.0.0.weight has shape [8, 15] but the config needs [128, 39]"
        ),
        "{err}"
    );
    let o = render(&config, "tiny");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.path().join("tiny/render_nerf.gif").is_file());
    // One flipped byte inside a tensor's data: the zip CRC no longer matches, which PyTorch
    // would load silently; import-torch refuses it and writes nothing.
    let mut bytes = std::fs::read(&fixture).unwrap();
    let at = bytes.windows(6).position(|w| w == b"data/0").unwrap() + 200;
    bytes[at] ^= 0xFF;
    let damaged = dir.path().join("damaged.pth");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = dir.path().join("x.safetensors");
    let o = common::nerf_command()
        .arg("import-torch")
        .arg(&damaged)
        .arg("--config")
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = stderr(&o);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("is corrupt (Invalid checksum)"), "{err}");
    assert!(!out.exists());
}
