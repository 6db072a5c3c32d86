//! Checkpoint paths, the numbers inside checkpoints and checkpoints that cannot be written,
//! through the binary: one rule resolves a path for every command (a directory's one
//! checkpoint, an error naming several, a fresh training run in an empty one, a relative
//! path's absolute form in its error); every count read from a checkpoint's metadata is
//! checked before anything is sized by it; a checkpoint write that fails (a full disk) ends
//! the run in one line, leaves no temporary file and no log line past the checkpoint.

mod common;

use std::path::Path;

use common::{
    lego_scratch, logged_steps, nerf, nerf_in, one_line_error, render_args, stderr, temp_files,
};

/// `nerf render` of the lego NeRF from `checkpoint`, small, into `out`.
fn render(checkpoint: &Path, out: &Path) -> std::process::Output {
    nerf(&render_args(
        "lego",
        out,
        &[
            "--checkpoint",
            checkpoint.to_str().unwrap(),
            "data.image_size=[8,8]",
            "cameras.n_poses=1",
            "sampler.n_pts_per_ray=8",
        ],
    ))
}

#[test]
fn a_directory_gives_its_one_checkpoint_and_names_several() {
    let (dir, ckpts) = common::scratch("ckpts");
    let out = dir.path().join("out");
    // Empty: an error naming the directory.
    std::fs::create_dir(&ckpts).unwrap();
    let err = one_line_error(&render(&ckpts, &out));
    assert!(
        err.contains(&format!("{} holds no checkpoint", ckpts.display())),
        "{err}"
    );
    // One: it is used, and said.
    common::save_seeded_checkpoint(&ckpts.join("a.safetensors"), &[]);
    let o = render(&ckpts, &out);
    assert!(o.status.success(), "{}", stderr(&o));
    let loaded = format!("loaded {}", ckpts.join("a.safetensors").display());
    assert!(stderr(&o).contains(&loaded), "{}", stderr(&o));
    // Two: an error naming both, and nothing written.
    common::save_seeded_checkpoint(&ckpts.join("b.safetensors"), &[]);
    let out2 = dir.path().join("out2");
    let err = one_line_error(&render(&ckpts, &out2));
    assert!(
        err.contains("holds several checkpoints (a.safetensors, b.safetensors)"),
        "{err}"
    );
    assert!(!out2.exists());
    // The config's training.checkpoint_path follows the same rule.
    let o = nerf(&[
        "eval",
        "--config",
        "lego",
        &format!("training.checkpoint_path={}", ckpts.display()),
    ]);
    let err = one_line_error(&o);
    assert!(err.contains("several checkpoints"), "{err}");
}

#[test]
fn a_missing_relative_checkpoint_says_where_it_was_looked_for() {
    let dir = tempfile::tempdir().unwrap();
    let o = nerf_in(
        dir.path(),
        &[
            "render",
            "--config",
            "lego",
            "--checkpoint",
            "runs/model.safetensors",
        ],
    );
    let err = one_line_error(&o);
    let tried = dir
        .path()
        .canonicalize()
        .unwrap()
        .join("runs/model.safetensors");
    assert!(
        err.contains("relative to the working directory")
            && err.contains(&tried.display().to_string()),
        "{err}"
    );
}

#[test]
fn training_refuses_several_checkpoints_and_starts_fresh_in_an_empty_directory() {
    let Some((data, dir)) = lego_scratch() else {
        return;
    };
    let ckpts = dir.path().join("ckpts");
    std::fs::create_dir(&ckpts).unwrap();
    for name in ["x.safetensors", "y.safetensors"] {
        common::save_seeded_checkpoint(&ckpts.join(name), &[]);
    }
    let mut train = common::tiny_train(&ckpts, &data, 1, 1);
    let o = train.stderr(std::process::Stdio::piped()).output().unwrap();
    let err = one_line_error(&o);
    assert!(
        err.contains("training.checkpoint_path")
            && err.contains("several checkpoints (x.safetensors, y.safetensors)"),
        "{err}"
    );
    assert!(!ckpts.join("nerf_lego.safetensors").exists());
    // Empty: a fresh run, said on stderr, writing into the directory.
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let mut train = common::tiny_train(&empty, &data, 1, 1);
    let o = train.stderr(std::process::Stdio::piped()).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("starting a fresh run"),
        "{}",
        stderr(&o)
    );
    assert!(empty.join("nerf_lego.safetensors").is_file());
}

/// A safetensors file with `header` (JSON) and `data` bytes.
fn safetensors_bytes(header: &str, data: &[u8]) -> Vec<u8> {
    let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
    bytes.extend(header.as_bytes());
    bytes.extend(data);
    bytes
}

#[test]
fn counts_in_a_checkpoint_are_checked_before_anything_is_sized_by_them() {
    let Some((data, dir, good)) = common::lego_trained("good", 1, 1) else {
        return;
    };
    let (tensors, info) = common::load_trained(&good);
    let mut tensors: Vec<(String, candle_core::Tensor)> = tensors.into_iter().collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let crafted = |name: &str, edit: &dyn Fn(&mut nerf::CheckpointInfo)| {
        let mut info = info.clone();
        edit(&mut info);
        let d = dir.path().join(name);
        nerf::io::checkpoint::save(&d.join("nerf_lego.safetensors"), &tensors, info).unwrap();
        d
    };
    // Each crafted file: `nerf train` resuming from it fails in one line naming the key.
    let cases: Vec<(&str, std::path::PathBuf)> = vec![
        // 2^62 rays per step panicked with "capacity overflow" before.
        (
            "rays_per_step",
            crafted("rays62", &|i| i.rays_per_step = 1 << 62),
        ),
        // Within the file's limit, past what a step of this config may take.
        (
            "rays_per_step",
            crafted("rays20", &|i| i.rays_per_step = 1 << 20),
        ),
        ("epoch", crafted("epoch", &|i| i.epoch = 1 << 40)),
        ("adam_step", crafted("adam", &|i| i.adam_step = 1 << 50)),
        // Past the 100 steps of an epoch on lego.
        (
            "step_in_epoch",
            crafted("step", &|i| i.step_in_epoch = 5000),
        ),
        (
            "wall_seconds",
            crafted("wall", &|i| i.wall_seconds = f64::NAN),
        ),
    ];
    for (key, ckpt) in cases {
        let mut train = common::tiny_train(&ckpt, &data, 2, 1);
        let o = train.stderr(std::process::Stdio::piped()).output().unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{key}: {err}");
        let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
        assert_eq!(errors.len(), 1, "{key}: {err}");
        assert!(
            errors[0].contains(&format!("metadata {key}")),
            "{key}: {err}"
        );
        assert!(!err.contains("panicked"), "{key}: {err}");
    }
    // A tensor whose shape needs far more bytes than the file holds.
    let huge = dir.path().join("huge.safetensors");
    let header = r#"{"mlp_xyz.mlp.0.0.weight":{"dtype":"F32","shape":[1099511627776,1099511627776],"data_offsets":[0,4]}}"#;
    std::fs::write(&huge, safetensors_bytes(header, &[0; 4])).unwrap();
    let err = one_line_error(&render(&huge, &dir.path().join("o")));
    assert!(err.contains("corrupt"), "{err}");
    // A count that does not parse is named too.
    let bad = dir.path().join("bad.safetensors");
    let header =
        r#"{"__metadata__":{"epoch":"-1"},"x":{"dtype":"F32","shape":[1],"data_offsets":[0,4]}}"#;
    std::fs::write(&bad, safetensors_bytes(header, &[0; 4])).unwrap();
    let err = one_line_error(&render(&bad, &dir.path().join("o")));
    assert!(err.contains("bad metadata epoch"), "{err}");
}

/// `command` with file sizes limited to `bytes` (`RLIMIT_FSIZE`) and SIGXFSZ ignored: a write
/// past the limit fails with EFBIG, as on a full disk.
fn with_file_size_limit(command: &mut std::process::Command, bytes: u64) {
    use std::os::unix::process::CommandExt;
    // SAFETY: between fork and exec only async-signal-safe calls (signal, setrlimit).
    unsafe {
        command.pre_exec(move || {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let limit = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

#[test]
fn a_checkpoint_that_cannot_be_written_ends_the_run_in_one_line_and_the_log_stays_behind() {
    let Some((data, _dir, ckpt)) = common::lego_trained("c", 1, 5) else {
        return;
    };
    let file = ckpt.join("nerf_lego.safetensors");
    let before = std::fs::read(&file).unwrap();
    let log_size = std::fs::metadata(ckpt.join("nerf_lego.log.jsonl"))
        .unwrap()
        .len();
    // Room for the log, none for the checkpoint (measured: a 9.9 KB log, a 33 KB checkpoint).
    assert!(
        log_size * 2 < before.len() as u64,
        "{log_size} {}",
        before.len()
    );
    let mut command = common::tiny_train(&ckpt, &data, 2, 5);
    command.stderr(std::process::Stdio::piped());
    with_file_size_limit(&mut command, (log_size + before.len() as u64) / 2);
    let out = command.output().unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.contains("error")).collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(
        errors[0].starts_with("error: cannot write checkpoint")
            && errors[0].contains("File too large"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().last(), Some(errors[0]));
    assert!(temp_files(&ckpt).is_empty(), "{:?}", temp_files(&ckpt));
    // The checkpoint is the old one, and the log holds none of the lost epoch's steps.
    assert_eq!(std::fs::read(&file).unwrap(), before);
    assert_eq!(logged_steps(&ckpt), (1..=100).collect::<Vec<u64>>());
    // The run resumes from it once there is room.
    common::tiny_train_ok(&ckpt, &data, 2, 5);
    assert_eq!(common::load_trained(&ckpt).1.adam_step, 200);
    assert_eq!(logged_steps(&ckpt), (1..=200).collect::<Vec<u64>>());
}

#[test]
fn a_missing_checkpoint_points_to_a_shipped_model_that_renders_well_with_this_config() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."));
    let cases = [
        // The homework's dense render config: the densely trained model, or the shipped
        // grid-trained one with the config it was trained for; never the latter densely.
        (
            "nerf_lego_render",
            "--checkpoint checkpoints/homework/nerf_lego.safetensors",
            "nerf render --config lego",
        ),
        // A hash-grid config: the hash-grid model, not the MLP's checkpoint.
        (
            "lego_ngp",
            "checkpoints/ngp_lego.safetensors",
            "nerf render --config lego_ngp",
        ),
    ];
    for (config, checkpoint, command) in cases {
        let err = one_line_error(&nerf_in(dir.path(), &render_args(config, "out", &[])));
        assert!(err.contains(checkpoint), "{config}: {err}");
        assert!(err.contains(command), "{config}: {err}");
        assert!(err.contains("relative to the working directory"), "{err}");
        assert!(!dir.path().join("out").exists());
    }
    // What the first hint suggests renders from the repository root (small, to stay quick).
    let out = dir.path().join("homework_render");
    let o = nerf_in(
        root,
        &[
            "run",
            "--config",
            "nerf_lego_render",
            "--checkpoint",
            "checkpoints/homework/nerf_lego.safetensors",
            "--out-dir",
            out.to_str().unwrap(),
            "data.image_size=[16,16]",
            "cameras.n_poses=2",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("render_nerf.gif").is_file());
}

#[test]
fn a_fifo_as_checkpoint_is_refused_without_blocking() {
    let (dir, fifo) = common::scratch("model.safetensors");
    common::make_fifo(&fifo);
    let out = dir.path().join("out");
    let err = one_line_error(&render(&fifo, &out));
    assert!(err.contains("not a regular file"), "{err}");
    assert!(!out.exists());
}
