//! The helpers of `nerf process`'s tests (`apps/nerf/tests/process.rs`, `apps/nerf/tests/process_video.rs`): the
//! command run several ways, stand-in COLMAP scripts, whether the real tools are installed,
//! and lego's true cameras to compare recovered ones with.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::{DMat3, DVec3};
use nerf::core::camera::alignment::{align_by_orientations, CameraPair};

/// `nerf process --images IMAGES --out OUT`, with `colmap` (when given) as `NERF_COLMAP`.
pub fn process(images: &Path, out: &Path, colmap: Option<&Path>) -> Output {
    let mut command = super::nerf_command();
    command
        .args(["process", "--images"])
        .arg(images)
        .arg("--out")
        .arg(out);
    if let Some(colmap) = colmap {
        command.env("NERF_COLMAP", colmap);
    }
    command.output().expect("run nerf")
}

/// A folder of `n` copies of a small PNG.
pub fn photos(dir: &Path, n: usize) -> PathBuf {
    let photos = dir.join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    for i in 0..n {
        image::RgbImage::from_pixel(8, 8, image::Rgb([i as u8, 50, 90]))
            .save(photos.join(format!("p{i}.png")))
            .unwrap();
    }
    photos
}

/// The error of a run that failed after progress lines: exit code 1, no panic, and the last
/// line of stderr the only `error:` line; returns that line.
pub fn last_line_error(o: &Output) -> String {
    let err = super::stderr(o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let last = err.trim_end().lines().last().unwrap_or("").to_string();
    assert!(last.starts_with("error: "), "{err}");
    assert_eq!(err.matches("error: ").count(), 1, "{err}");
    last
}

/// Held by every test here, so that they run one at a time: run beside the others, the real
/// mapper registered 0 of the 24 views in all 6 of its runs (each grew a model of 5 or 6
/// images and dropped it) twice in a row, where alone it registered about 21.
pub fn alone() -> std::sync::MutexGuard<'static, ()> {
    static HEAVY: std::sync::Mutex<()> = std::sync::Mutex::new(());
    HEAVY
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// An executable shell script `dir/colmap` with `body`.
pub fn fake_colmap(dir: &Path, body: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let path = dir.join("colmap");
    std::fs::write(&path, format!("#!/bin/sh\n{body}\n")).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

/// Whether the tool `what` runs here (`$env`, else `program` on PATH, run with `arg`); else a
/// visible skip, and a failure under `CI=true` (`.ci/install` installs Debian's package of
/// `package`), as for Chromium.
pub fn tool_installed(what: &str, (env, program, arg): (&str, &str, &str), package: &str) -> bool {
    use std::io::Write;
    let test = super::test_name();
    let program = std::env::var_os(env).unwrap_or_else(|| program.into());
    let runs = Command::new(&program)
        .arg(arg)
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .is_ok();
    if !runs {
        let why = format!(
            "{what} not found ({} does not run; sudo apt-get install {package}, or run .ci/install)",
            program.to_string_lossy()
        );
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("{test}: {why}, and CI must have it");
        }
        let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
    }
    runs
}

/// Whether COLMAP runs here (`colmap` on PATH, or `$NERF_COLMAP`); else a visible skip, and
/// a failure under `CI=true` ([`tool_installed`]).
pub fn colmap_installed() -> bool {
    let command = ("NERF_COLMAP", "colmap", "help");
    tool_installed("COLMAP", command, "colmap")
}

/// Lego's views of `split` (`train`; `test`, a spiral around the model, 3.6° a view) as
/// (image name, OpenGL camera → world rotation, centre).
pub fn lego_cameras(lego: &Path, split: &str) -> Vec<(String, DMat3, DVec3)> {
    let text = std::fs::read_to_string(lego.join(format!("transforms_{split}.json"))).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            let name = f["file_path"].as_str().unwrap().rsplit('/').next().unwrap();
            let (rotation, centre) = rotation_and_centre(&f["transform_matrix"]);
            (format!("{name}.png"), rotation, centre)
        })
        .collect()
}

/// The frames of the capture `out`'s `transforms.json`.
pub fn written_frames(out: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(out.join("transforms.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json["frames"].as_array().unwrap().clone()
}

/// Runs `run` (a `nerf process` of `what`), asserts that it succeeded and prints how long it
/// took; returns its stdout followed by its stderr (the log).
pub fn timed_ok(what: &str, run: impl FnOnce() -> Output) -> String {
    let start = std::time::Instant::now();
    let o = run();
    let seconds = start.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", super::stderr(&o));
    eprintln!("nerf process {what}: {seconds:.1} s; {stdout}");
    format!("{stdout}{}", super::stderr(&o))
}

/// Recovered (r) against true (t) cameras: asserts that `t = A·r` for one rotation `A` to
/// within 1.5°, and the centres `C_t = s·A·C_r + b` to within 2% of the true cameras' mean
/// distance from the origin ([`align_by_orientations`]).
pub fn assert_aligned(pairs: &[CameraPair]) {
    let alignment = align_by_orientations(pairs);
    let rotation_errors = alignment.rotation_errors_degrees;
    let radius = pairs.iter().map(|p| p.true_centre.length()).sum::<f64>() / pairs.len() as f64;
    let centre_errors: Vec<f64> = alignment.centre_errors.iter().map(|e| e / radius).collect();
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    eprintln!(
        "{} registered; rotation error max {:.3}°, centre error max {:.4} of the radius",
        pairs.len(),
        max(&rotation_errors),
        max(&centre_errors)
    );
    assert!(max(&rotation_errors) < 1.5, "{rotation_errors:?}");
    assert!(max(&centre_errors) < 0.02, "{centre_errors:?}");
}

/// The rotation and centre of a 4×4 camera → world matrix in JSON.
pub fn rotation_and_centre(m: &serde_json::Value) -> (DMat3, DVec3) {
    let at = |i: usize, j: usize| m[i][j].as_f64().unwrap();
    let column = |j: usize| DVec3::new(at(0, j), at(1, j), at(2, j));
    (DMat3::from_cols(column(0), column(1), column(2)), column(3))
}

/// Whether Python imports pycolmap here (`python3`, or `$NERF_PYTHON`); else a visible skip,
/// and a failure under `CI=true` (`.ci/install` installs the wheel).
pub fn pycolmap_installed() -> bool {
    use std::io::Write;
    let python = std::env::var_os("NERF_PYTHON").unwrap_or_else(|| "python3".into());
    let imports = Command::new(&python)
        .args(["-c", "import pycolmap"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !imports {
        let test = super::test_name();
        let why = "pycolmap not found (pip install pycolmap, or run .ci/install)";
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("{test}: {why}, and CI must have it");
        }
        let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
    }
    imports
}

/// `nerf process --images IMAGES --out OUT ARGS`, without `NERF_COLMAP`'s stand-ins.
pub fn process_with(images: &Path, out: &Path, args: &[&str]) -> Output {
    super::nerf_command()
        .arg("process")
        .args(args)
        .arg("--images")
        .arg(images)
        .arg("--out")
        .arg(out)
        .output()
        .expect("run nerf")
}

/// A stand-in COLMAP in `dir` (`dir/colmap`, [`fake_colmap`]) whose mapper copies the
/// prepared model `models/seed<k>` ([`ring_models`]) of its `--random_seed k`, and whose
/// refinement stages (point_filtering, bundle_adjuster) run `refine` (`$input` and `$out`
/// their folders); `prelude` runs first.
pub fn seeded_colmap(dir: &Path, models: &Path, prelude: &str, refine: &str) -> PathBuf {
    fake_colmap(
        dir,
        &format!(
            "{prelude}stage=$1; input=; out=; seed=\nwhile [ $# -gt 0 ]; do case \"$1\" in --input_path) input=\"$2\";; --output_path) out=\"$2\";; --random_seed) seed=\"$2\";; esac; shift; done\ncase $stage in mapper) mkdir -p \"$out/0\" && cp {}/seed$seed/* \"$out/0/\";; point_filtering|bundle_adjuster) {refine};; esac",
            models.display()
        ),
    )
}

/// The refinement of [`seeded_colmap`] that copies its input model to its output.
pub const COPY_INPUT: &str = "cp \"$input\"/* \"$out/\"";

/// COLMAP text models of `names` seen from a ring of cameras (radius 4, height 2), one per
/// seed under `dir/seed<k>`: seed 0 has `flipped` at its mirror place across the ring's axis,
/// seed 2 registered only the first 3 images, the others are exact in gauges of their own
/// (scaled and shifted).
pub fn ring_models(dir: &Path, names: &[String], flipped: &str, seeds: u64) -> PathBuf {
    let models = dir.join("models");
    for seed in 0..seeds {
        let folder = models.join(format!("seed{seed}"));
        std::fs::create_dir_all(&folder).unwrap();
        std::fs::write(folder.join("cameras.txt"), "1 SIMPLE_PINHOLE 8 8 10 4 4\n").unwrap();
        std::fs::write(folder.join("points3D.txt"), "# no points\n").unwrap();
        let mut images = String::new();
        for (i, name) in names.iter().enumerate() {
            if seed == 2 && i >= 3 {
                break;
            }
            let a = i as f64 * std::f64::consts::TAU / names.len() as f64;
            let mut c = DVec3::new(4.0 * a.cos(), 4.0 * a.sin(), 2.0);
            if seed == 0 && name == flipped {
                c = DVec3::new(-c.x, -c.y, c.z);
            }
            let c = (1.0 + seed as f64) * c + DVec3::new(seed as f64, 0.5, -1.0);
            // Identity rotation: the translation is -C.
            images += &format!("{} 1 0 0 0 {} {} {} 1 {name}\n\n", i + 1, -c.x, -c.y, -c.z);
        }
        std::fs::write(folder.join("images.txt"), images).unwrap();
    }
    models
}
