//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the `nerf` binary with `args`.
pub fn nerf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nerf"))
        .args(args)
        .output()
        .expect("run nerf")
}

/// Runs the `nerf` binary with `args` in the working directory `dir` (the homework's configs
/// name files relative to it).
pub fn nerf_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nerf"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("run nerf")
}

/// The homework's verbatim config `name` (`../shared/homework/configs/<name>.yaml`), or a
/// visible skip.
pub fn homework_config(name: &str, test: &str) -> Option<PathBuf> {
    shared("homework/configs", &format!("{name}.yaml"), test)
        .map(|d| d.join(format!("{name}.yaml")))
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

/// `../shared/<relative>` beside the checkout, when `marker` exists inside it. When it does
/// not, the test says so on the terminal (written past the test harness's capture, so a
/// reader of `cargo test` sees it) and is skipped — except under CI (`CI=true`), where the
/// shared data must be present and its absence fails the test.
pub fn shared(relative: &str, marker: &str, test: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
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
pub fn lego_dir(test: &str) -> Option<PathBuf> {
    shared("data/lego", "transforms_train.json", test)
}

/// The homework's reference images in `../shared/reference_images`, or a visible skip.
pub fn reference_dir(test: &str) -> Option<PathBuf> {
    shared("reference_images", "render_cube.gif", test)
}

/// Largest absolute difference between two equally long slices.
pub fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}
