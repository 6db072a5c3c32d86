//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod lego_capture;
pub mod process_tools;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh scratch directory (removed when the `TempDir` drops) and the path `name` inside it.
pub fn scratch(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    (dir, path)
}

/// The repository's root, two folders above this package's (`apps/nerf`): where the `nerf`
/// binary runs in the tests, so that the paths it reads by default (`checkpoints/`,
/// `../shared/data`) are the checkout's.
pub const REPO_ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");

/// The `nerf` binary as a command, run in [`REPO_ROOT`] unless the caller says otherwise.
pub fn nerf_command() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_nerf"));
    command.current_dir(REPO_ROOT);
    command
}

/// Runs the `nerf` binary with `args`.
pub fn nerf(args: &[&str]) -> Output {
    nerf_command().args(args).output().expect("run nerf")
}

/// The standard output of a run that must have succeeded (a failure shows its stderr).
pub fn succeeded_stdout(o: &Output) -> String {
    assert!(o.status.success(), "{}", stderr(o));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Runs the `nerf` binary with `args` and asserts that it succeeded (a failure shows its
/// stderr).
pub fn nerf_ok(args: &[&str]) -> Output {
    let o = nerf(args);
    assert!(o.status.success(), "{}", stderr(&o));
    o
}

/// Runs the `nerf` binary with `args` in the working directory `dir` (the homework's configs
/// name files relative to it).
pub fn nerf_in(dir: &Path, args: &[&str]) -> Output {
    nerf_command()
        .current_dir(dir)
        .args(args)
        .output()
        .expect("run nerf")
}

/// The homework's verbatim config `name` (`../shared/homework/configs/<name>.yaml`), or a
/// visible skip.
pub fn homework_config(name: &str) -> Option<PathBuf> {
    shared("homework/configs", &format!("{name}.yaml")).map(|d| d.join(format!("{name}.yaml")))
}

/// The error of a run that failed cleanly: exit code 1, one line on stderr, no panic (each
/// asserted); returns that stderr.
pub fn one_line_error(o: &Output) -> String {
    let err = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(!err.contains("panicked"), "{err}");
    err
}

/// A run's stderr as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// Shape and values of a float32 `.npy` file.
pub fn read_npy(path: &Path) -> (Vec<u64>, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    let npy = npyz::NpyFile::new(&bytes[..]).unwrap();
    let shape = npy.shape().to_vec();
    (shape, npy.into_vec::<f32>().unwrap())
}

/// The name of the running test (libtest runs each test on a thread named by its path), for
/// skip and failure messages, so that no test writes its own name again.
pub fn test_name() -> String {
    let thread = std::thread::current();
    let path = thread.name().unwrap_or("this test");
    path.rsplit("::").next().unwrap_or(path).to_string()
}

/// `../shared/<relative>` beside the checkout, when `marker` exists inside it. When it does
/// not, the test says so on the terminal (written past the test harness's capture, so a
/// reader of `cargo test` sees it) and is skipped — except under CI (`CI=true`), where the
/// shared data must be present and its absence fails the test.
pub fn shared(relative: &str, marker: &str) -> Option<PathBuf> {
    let test = test_name();
    let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("../shared")
        .join(relative);
    if p.join(marker).exists() {
        return Some(p);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "{test}: {} not found, and CI must have it",
            p.join(marker).display()
        );
    }
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: {} not found",
        p.join(marker).display()
    );
    None
}

/// The lego scene in `../shared/data/lego`, or a visible skip.
pub fn lego_dir() -> Option<PathBuf> {
    shared("data/lego", "transforms_train.json")
}

/// The homework's reference images in `../shared/reference_images`, or a visible skip.
pub fn reference_dir() -> Option<PathBuf> {
    shared("reference_images", "render_cube.gif")
}

/// Largest absolute difference between two equally long slices.
pub fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// The largest difference between the channels of two RGB images, pixel by pixel (as far as
/// both go).
pub fn max_channel_difference(a: &image::RgbImage, b: &image::RgbImage) -> u8 {
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap()
}

/// The largest difference between 8-bit image bytes, read as `b / 255`, and the float values
/// they were written from, pairwise (as far as both go).
pub fn max_byte_difference(bytes: &[u8], values: &[f32]) -> f32 {
    bytes
        .iter()
        .zip(values)
        .map(|(b, v)| (*b as f32 / 255.0 - v).abs())
        .fold(0.0, f32::max)
}

/// Writes a freshly initialised model of the lego config (with `overrides`), seeded with
/// `seed`, to `path`, with `info` as its metadata.
pub fn save_seeded_checkpoint(path: &Path, overrides: &[&str]) {
    save_seeded_checkpoint_with(path, overrides, 0, nerf::CheckpointInfo::default());
}

/// [`save_seeded_checkpoint`] with a seed and metadata.
pub fn save_seeded_checkpoint_with(
    path: &Path,
    overrides: &[&str],
    seed: u64,
    info: nerf::CheckpointInfo,
) {
    let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
    let config = nerf::config::Config::load("lego", &overrides).unwrap();
    let state = nerf::NerfState::seeded(
        &config.nerf_params().unwrap(),
        seed,
        &candle_core::Device::Cpu,
    )
    .unwrap();
    nerf::io::checkpoint::save(
        path,
        &nerf::io::checkpoint::model_tensors(&state.varmap),
        info,
    )
    .unwrap();
}

/// The tiny NeRF's training settings (no rendering during training, 32 rays a batch, learning
/// rate 0.002), as config overrides.
pub const TINY_NERF_TRAINING: [&str; 3] = [
    "training.render_interval=1000",
    "training.batch_size=32",
    "training.lr=0.002",
];

/// The tiny NeRF's model and images, as config overrides: a 3-layer 16-wide trunk (8-wide
/// direction branch), 8 samples per ray, 8×8 images.
pub const TINY_NERF_MODEL: [&str; 6] = [
    "implicit_function.n_hidden_neurons_xyz=16",
    "implicit_function.n_hidden_neurons_dir=8",
    "implicit_function.n_layers_xyz=3",
    "implicit_function.append_xyz=[2]",
    "sampler.n_pts_per_ray=8",
    "data.image_size=[8,8]",
];

/// A tiny NeRF training run of `nerf train` on the lego data in `data` (8×8 images, 8 samples
/// per ray, a 3-layer 16-wide trunk: about 0.1 s per epoch) into `ckpt_dir`, with a checkpoint
/// every `checkpoint_interval` epochs. Its stdout and stderr go nowhere unless the caller says.
pub fn tiny_train(
    ckpt_dir: &Path,
    data: &Path,
    epochs: usize,
    checkpoint_interval: usize,
) -> Command {
    let mut c = nerf_command();
    c.args([
        "train",
        "--config",
        "nerf_lego",
        "--data-dir",
        data.to_str().unwrap(),
        &format!("training.checkpoint_path={}", ckpt_dir.display()),
        &format!("training.num_epochs={epochs}"),
        &format!("training.checkpoint_interval={checkpoint_interval}"),
    ]);
    c.args(TINY_NERF_TRAINING);
    c.args(TINY_NERF_MODEL);
    c.args(["--out-dir", ckpt_dir.join("images").to_str().unwrap()]);
    c.stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    c
}

/// The Chromium executable for the browser test: `$CHROMIUM`, else `/usr/bin/chromium`
/// (Debian's package, which `.ci/install` installs), or a visible skip — a failure under
/// `CI=true`, like the shared data.
pub fn chromium() -> Option<PathBuf> {
    let test = test_name();
    let path = std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    if path.is_file() {
        return Some(path);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "{test}: Chromium not found at {} (set $CHROMIUM or run .ci/install), and CI must have it",
            path.display()
        );
    }
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: Chromium not found at {} (set $CHROMIUM or run .ci/install)",
        path.display()
    );
    None
}

/// The steps of a training log in `ckpt_dir`, in order.
pub fn logged_steps(ckpt_dir: &Path) -> Vec<u64> {
    std::fs::read_to_string(ckpt_dir.join("nerf_lego.log.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["step"]
                .as_u64()
                .unwrap()
        })
        .collect()
}

/// The names of the temporary files in `dir`.
pub fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

/// Makes a FIFO (named pipe) at `path`, for the tests of readers and writers that must not
/// block on one.
pub fn make_fifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

/// The names in `dir`, sorted.
pub fn sorted_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    names
}

/// Runs [`tiny_train`] to its end and asserts that it succeeded.
pub fn tiny_train_ok(ckpt_dir: &Path, data: &Path, epochs: usize, checkpoint_interval: usize) {
    assert!(tiny_train(ckpt_dir, data, epochs, checkpoint_interval)
        .status()
        .unwrap()
        .success());
}

/// The tensors and metadata of the checkpoint that training writes in `ckpt_dir`
/// (`nerf_lego.safetensors`), loaded on the CPU.
pub fn load_trained(
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

/// The lego scene in `../shared/data/lego` and a fresh scratch directory for the test's
/// files, or a visible skip (as [`lego_dir`]).
pub fn lego_scratch() -> Option<(PathBuf, tempfile::TempDir)> {
    let data = lego_dir()?;
    Some((data, tempfile::tempdir().unwrap()))
}

/// `nerf render --config CONFIG --out-dir OUT MORE…` (MORE: further flags and overrides).
pub fn render_args<'a, P: AsRef<Path> + ?Sized>(
    config: &'a str,
    out: &'a P,
    more: &[&'a str],
) -> Vec<&'a str> {
    let out = out.as_ref().to_str().unwrap();
    [&["render", "--config", config, "--out-dir", out][..], more].concat()
}

/// `nerf COMMAND --config CONFIG --data-dir DATA MORE…` (MORE: further flags and overrides).
pub fn data_args<'a>(
    command: &'a str,
    config: &'a str,
    data: &'a Path,
    more: &[&'a str],
) -> Vec<&'a str> {
    let data = data.to_str().unwrap();
    [&[command, "--config", config, "--data-dir", data][..], more].concat()
}

/// `nerf export KIND --config CONFIG EXTRA… --out OUT`.
pub fn export_args<'a>(
    kind: &'a str,
    config: &'a str,
    extra: &[&'a str],
    out: &'a str,
) -> Vec<&'a str> {
    [
        &["export", kind, "--config", config][..],
        extra,
        &["--out", out],
    ]
    .concat()
}

/// [`lego_scratch`] with a tiny NeRF trained into the scratch directory's `name` by
/// [`tiny_train_ok`] (`epochs` epochs, a checkpoint every `checkpoint_interval`): the data, the
/// scratch directory and that checkpoint directory, or a visible skip.
pub fn lego_trained(
    name: &str,
    epochs: usize,
    checkpoint_interval: usize,
) -> Option<(PathBuf, tempfile::TempDir, PathBuf)> {
    let (data, dir) = lego_scratch()?;
    let ckpt_dir = dir.path().join(name);
    tiny_train_ok(&ckpt_dir, &data, epochs, checkpoint_interval);
    Some((data, dir, ckpt_dir))
}

/// The RGBA frames of the GIF at `path`.
pub fn gif_frames(path: &Path) -> Vec<Vec<u8>> {
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

/// `/info.json` of `nerf view ARGS…` on a free port (the server is killed after).
pub fn view_info(args: &[&str]) -> serde_json::Value {
    use std::io::{BufRead, BufReader, Read, Write};
    let mut child = nerf_command()
        .args(["view", "--port", "0"])
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .to_string();
    let mut stream = std::net::TcpStream::connect(&addr).unwrap();
    write!(
        stream,
        "GET /info.json HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut bytes = Vec::new();
    stream.read_to_end(&mut bytes).unwrap();
    let _ = child.kill();
    let _ = child.wait();
    let body = String::from_utf8_lossy(&bytes).to_string();
    let json = body.split("\r\n\r\n").nth(1).expect("no body");
    serde_json::from_str(json).unwrap()
}
