//! `nerf process`: its one-line errors (no photos, COLMAP missing, a failed stage, nothing
//! registered) and its choice among mapper runs, made with a stand-in `colmap` script where
//! COLMAP's own behaviour is not the point, and a real COLMAP run on 24 lego training views whose recovered cameras must agree
//! with lego's true cameras up to a similarity transform.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::{DMat3, DVec3};
use nerf::core::camera_alignment::{align_by_orientations, CameraPair};
use nerf::io::dataset::{read_capture_split, SceneFormat, Split};

/// `nerf process --images IMAGES --out OUT`, with `colmap` (when given) as `NERF_COLMAP`.
fn process(images: &Path, out: &Path, colmap: Option<&Path>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_nerf"));
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
fn photos(dir: &Path, n: usize) -> PathBuf {
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
fn last_line_error(o: &Output) -> String {
    let err = common::stderr(o);
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
fn alone() -> std::sync::MutexGuard<'static, ()> {
    static HEAVY: std::sync::Mutex<()> = std::sync::Mutex::new(());
    HEAVY
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// An executable shell script `dir/colmap` with `body`.
fn fake_colmap(dir: &Path, body: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let path = dir.join("colmap");
    std::fs::write(&path, format!("#!/bin/sh\n{body}\n")).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

#[test]
fn no_photos_and_missing_colmap_are_one_line_errors() {
    let _alone = alone();
    let (dir, out) = common::scratch("out");
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(empty.join("sub")).unwrap();
    std::fs::write(empty.join("notes.txt"), "not a photo").unwrap();
    let err = common::one_line_error(&process(&empty, &out, None));
    assert!(err.contains("no images in"), "{err}");
    assert!(!out.exists(), "{err}");

    let photos = photos(dir.path(), 2);
    let err = common::one_line_error(&process(&photos, &out, Some(Path::new("/nonexistent"))));
    assert!(err.contains("COLMAP is missing"), "{err}");
    assert!(err.contains("sudo apt-get install colmap"), "{err}");
    assert!(!out.join("transforms.json").exists(), "{err}");

    // pycolmap asked for and missing: one line, before OUT is touched.
    let o = Command::new(env!("CARGO_BIN_EXE_nerf"))
        .args(["process", "--sfm", "pycolmap", "--images"])
        .arg(&photos)
        .arg("--out")
        .arg(&out)
        .env("NERF_PYTHON", "/nonexistent/python3")
        .output()
        .unwrap();
    let err = common::one_line_error(&o);
    assert!(err.contains("pycolmap is missing"), "{err}");
    assert!(err.contains("pip install pycolmap"), "{err}");
    assert!(!out.exists(), "{err}");
    // Retrieval matching needs pycolmap.
    let o = Command::new(env!("CARGO_BIN_EXE_nerf"))
        .args([
            "process",
            "--sfm",
            "colmap",
            "--matcher",
            "retrieval",
            "--images",
        ])
        .arg(&photos)
        .arg("--out")
        .arg(&out)
        .env("NERF_COLMAP", fake_colmap(dir.path(), "exit 0"))
        .output()
        .unwrap();
    let err = common::one_line_error(&o);
    assert!(err.contains("--matcher retrieval needs"), "{err}");
    assert!(!out.exists(), "{err}");
}

#[test]
fn photos_colmap_cannot_take_are_named_before_it_runs_and_links_are_not_followed() {
    let _alone = alone();
    let dir = tempfile::tempdir().unwrap();
    // A COLMAP that records that it ran: none of these cases may reach it.
    let marker = dir.path().join("colmap_ran");
    let colmap = fake_colmap(dir.path(), &format!("touch {}; exit 1", marker.display()));
    // What is wrong, how a folder of photos gets it, and what the error says.
    type Case<'a> = (&'a str, fn(&Path), &'a str);
    let cases: [Case; 3] = [
        (
            "a line break in a name",
            |p| {
                std::fs::copy(p.join("p0.png"), p.join("two\nlines.png"))
                    .map(drop)
                    .unwrap()
            },
            "name COLMAP cannot keep",
        ),
        (
            "a leading space",
            |p| {
                std::fs::copy(p.join("p0.png"), p.join(" p9.png"))
                    .map(drop)
                    .unwrap()
            },
            "name COLMAP cannot keep",
        ),
        (
            "a .jpg that is not a photo",
            |p| std::fs::write(p.join("notes.jpg"), b"shopping list").unwrap(),
            "notes.jpg: not a photo that decodes",
        ),
    ];
    for (i, (what, spoil, says)) in cases.iter().enumerate() {
        let photos = photos(&dir.path().join(format!("case{i}")), 4);
        spoil(&photos);
        let out = dir.path().join(format!("out{i}"));
        let err = common::one_line_error(&process(&photos, &out, Some(&colmap)));
        assert!(err.contains(says), "{what}: {err}");
        assert!(!out.exists(), "{what}: wrote {}", out.display());
        assert!(!marker.exists(), "{what}: COLMAP ran");
    }
    // Two links back up the tree: not followed (the walk was exponential), each photo listed
    // once, and a note says so.
    let photos = photos(&dir.path().join("loops"), 4);
    std::os::unix::fs::symlink(&photos, photos.join("again")).unwrap();
    std::fs::create_dir(photos.join("sub")).unwrap();
    std::os::unix::fs::symlink(&photos, photos.join("sub").join("again")).unwrap();
    let out = dir.path().join("out_loops");
    let o = process(&photos, &out, Some(&colmap));
    let log = common::stderr(&o);
    assert!(
        log.contains("symbolic links to folders not followed"),
        "{log}"
    );
    assert_eq!(common::sorted_names(&out.join("images")).len(), 4, "{log}");
}

#[test]
fn failed_stage_and_nothing_registered_are_one_line_errors() {
    let _alone = alone();
    let dir = tempfile::tempdir().unwrap();
    let photos = photos(dir.path(), 4);
    // A COLMAP whose matcher fails: the error names the stage and its log.
    let failing = fake_colmap(
        dir.path(),
        "case \"$1\" in *_matcher) echo 'matching went wrong' >&2; exit 3;; esac; exit 0",
    );
    let out = dir.path().join("out1");
    let err = last_line_error(&process(&photos, &out, Some(&failing)));
    assert!(err.contains("COLMAP's exhaustive_matcher failed"), "{err}");
    assert!(err.contains("exhaustive_matcher.log"), "{err}");
    assert!(err.contains("matching went wrong"), "{err}");
    assert!(!out.join("transforms.json").exists());
    let log = std::fs::read_to_string(out.join("colmap/exhaustive_matcher.log")).unwrap();
    assert!(log.contains("matching went wrong"), "{log}");
    // The failed run left OUT marked unfinished; the same command again starts over (here it
    // fails the same way, which shows it ran rather than refused).
    assert!(out.join(".nerf-process-unfinished").is_file());
    let o = process(&photos, &out, Some(&failing));
    assert!(
        common::stderr(&o).contains("held an unfinished run"),
        "{}",
        common::stderr(&o)
    );
    let err = last_line_error(&o);
    assert!(err.contains("COLMAP's exhaustive_matcher failed"), "{err}");

    // A COLMAP whose mapper makes no model: nothing registered.
    let idle = fake_colmap(dir.path(), "exit 0");
    let out = dir.path().join("out2");
    let err = last_line_error(&process(&photos, &out, Some(&idle)));
    assert!(err.contains("COLMAP registered 0 of 4 images"), "{err}");
    assert!(!out.join("transforms.json").exists());
    assert_eq!(common::sorted_names(&out.join("images")).len(), 4);

    // A COLMAP whose mapper registers 2 of the 4, and whose refinement would fail: too few
    // registered is what is said (the refinement is not run on so small a model).
    let two: Vec<String> = (0..2).map(|i| format!("p{i}.png")).collect();
    let models = ring_models(&dir.path().join("two"), &two, "none", 3);
    let small = seeded_colmap(dir.path(), &models, "", "echo refinement ran >&2; exit 1");
    let out = dir.path().join("out3");
    let err = last_line_error(&process(&photos, &out, Some(&small)));
    assert!(err.contains("COLMAP registered 2 of 4 images"), "{err}");
    assert!(!out.join("transforms.json").exists());
}

/// Whether the tool `what` runs here (`$env`, else `program` on PATH, run with `arg`); else a
/// visible skip, and a failure under `CI=true` (`.ci/install` installs Debian's package of
/// `package`), as for Chromium.
fn tool_installed(what: &str, (env, program, arg): (&str, &str, &str), package: &str) -> bool {
    use std::io::Write;
    let test = common::test_name();
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
fn colmap_installed() -> bool {
    let command = ("NERF_COLMAP", "colmap", "help");
    tool_installed("COLMAP", command, "colmap")
}

/// Lego's views of `split` (`train`; `test`, a spiral around the model, 3.6° a view) as
/// (image name, OpenGL camera → world rotation, centre).
fn lego_cameras(lego: &Path, split: &str) -> Vec<(String, DMat3, DVec3)> {
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
fn written_frames(out: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(out.join("transforms.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    json["frames"].as_array().unwrap().clone()
}

/// Runs `run` (a `nerf process` of `what`), asserts that it succeeded and prints how long it
/// took; returns its stdout.
fn timed_ok(what: &str, run: impl FnOnce() -> Output) -> String {
    let start = std::time::Instant::now();
    let o = run();
    let seconds = start.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", common::stderr(&o));
    eprintln!("nerf process {what}: {seconds:.1} s; {stdout}");
    stdout
}

/// Recovered (r) against true (t) cameras: asserts that `t = A·r` for one rotation `A` to
/// within 1.5°, and the centres `C_t = s·A·C_r + b` to within 2% of the true cameras' mean
/// distance from the origin ([`align_by_orientations`]).
fn assert_aligned(pairs: &[CameraPair]) {
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
fn rotation_and_centre(m: &serde_json::Value) -> (DMat3, DVec3) {
    let at = |i: usize, j: usize| m[i][j].as_f64().unwrap();
    let column = |j: usize| DVec3::new(at(0, j), at(1, j), at(2, j));
    (DMat3::from_cols(column(0), column(1), column(2)), column(3))
}

/// Whether Python imports pycolmap here (`python3`, or `$NERF_PYTHON`); else a visible skip,
/// and a failure under `CI=true` (`.ci/install` installs the wheel).
fn pycolmap_installed() -> bool {
    use std::io::Write;
    let python = std::env::var_os("NERF_PYTHON").unwrap_or_else(|| "python3".into());
    let imports = Command::new(&python)
        .args(["-c", "import pycolmap"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !imports {
        let test = common::test_name();
        let why = "pycolmap not found (pip install pycolmap, or run .ci/install)";
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            panic!("{test}: {why}, and CI must have it");
        }
        let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
    }
    imports
}

/// `nerf process --images IMAGES --out OUT ARGS`, without `NERF_COLMAP`'s stand-ins.
fn process_with(images: &Path, out: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nerf"))
        .arg("process")
        .args(args)
        .arg("--images")
        .arg(images)
        .arg("--out")
        .arg(out)
        .output()
        .expect("run nerf")
}

#[test]
fn colmap_recovers_lego_cameras() {
    let _alone = alone();
    let Some(lego) = common::lego_dir() else {
        return;
    };
    if !colmap_installed() {
        return;
    }
    recovers_lego_cameras(&lego, &["--sfm", "colmap"]);
}

#[test]
fn pycolmap_recovers_lego_cameras() {
    let _alone = alone();
    let Some(lego) = common::lego_dir() else {
        return;
    };
    if !pycolmap_installed() {
        return;
    }
    // Retrieval pairs (the Python side's bag of visual words) rather than every pair.
    let stdout = recovers_lego_cameras(&lego, &["--sfm", "pycolmap", "--matcher", "retrieval"]);
    // One mapper run by default.
    assert!(stdout.contains("1 mapper runs"), "{stdout}");
    assert!(stdout.contains("retrieval_matcher"), "{stdout}");
}

/// `nerf process ARGS` on 24 lego views recovers their cameras up to a similarity
/// ([`assert_aligned`]); returns its stdout.
fn recovers_lego_cameras(lego: &Path, sfm: &[&str]) -> String {
    // The 24 views nearest r_0's (within about 47°): lego's 100 views spread over a hemisphere
    // leave 24 consecutive ones too far apart to match on the object's few features.
    let truth = lego_cameras(lego, "train");
    let c0 = truth[0].2.normalize();
    let mut nearest: Vec<_> = truth.iter().collect();
    nearest.sort_by(|a, b| {
        let angle = |c: DVec3| c.normalize().dot(c0).clamp(-1.0, 1.0).acos();
        angle(a.2).total_cmp(&angle(b.2))
    });
    nearest.truncate(24);
    let (dir, photos) = common::scratch("photos");
    std::fs::create_dir_all(&photos).unwrap();
    for (name, _, _) in &nearest {
        std::fs::copy(lego.join("train").join(name), photos.join(name)).unwrap();
    }
    let out = dir.path().join("capture");
    // COLMAP's mapper is not repeatable (its RANSAC runs on several threads). In one full
    // suite run of four, four of six mapper runs registered nothing and the two that
    // registered 21 disagreed on most cameras. `nerf process` then keeps one run whole and
    // warns that no majority could say which is right; this test checks camera accuracy,
    // which such a run may lack, so it gives the whole process one more try after that
    // warning (or after no run registered anything), which starts over.
    let stdout = timed_ok(&format!("on 24 lego views with {sfm:?}"), || {
        let first = process_with(&photos, &out, sfm);
        let stderr = String::from_utf8_lossy(&first.stderr);
        let unsure = stderr.contains("COLMAP registered 0 of")
            || stderr.contains("disagree on most cameras");
        if !unsure {
            return first;
        }
        eprintln!(
            "the mapper runs gave no majority; trying once more: {}",
            common::stderr(&first)
        );
        process_with(&photos, &out, sfm)
    });

    let text = std::fs::read_to_string(out.join("transforms.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["camera_model"], "OPENCV");
    let frames = written_frames(&out);
    assert!(frames.len() >= 15, "{} of 24 registered", frames.len());
    // Frames are the kept mapper run's registered images, less any the other runs disputed.
    let (_, model) = nerf::io::colmap::find_model(&out.join("colmap")).unwrap();
    let registered = model.images.len();
    assert!(
        stdout.contains(&format!("{registered} of 24 images registered")),
        "{stdout}"
    );
    assert!(frames.len() <= registered, "{stdout}");
    let train = read_capture_split(&out, SceneFormat::Nerfstudio, Split::Train).unwrap();
    let test = read_capture_split(&out, SceneFormat::Nerfstudio, Split::Test).unwrap();
    assert_eq!(train.total_frames, frames.len());
    assert_eq!(train.frames.len() + test.frames.len(), frames.len());

    // Recovered (r) against true (t) cameras: t = A·r for one rotation A, and centres
    // C_t = s·A·C_r + b. A: the mean of the per-camera A_i = R_t·R_rᵀ.
    let pairs: Vec<CameraPair> = frames
        .iter()
        .map(|f| {
            let path = f["file_path"].as_str().unwrap();
            let name = path.strip_prefix("images/").unwrap();
            let (_, true_rotation, true_centre) = truth.iter().find(|(n, _, _)| n == name).unwrap();
            let (rotation, centre) = rotation_and_centre(&f["transform_matrix"]);
            CameraPair {
                true_rotation: *true_rotation,
                true_centre: *true_centre,
                rotation,
                centre,
            }
        })
        .collect();
    assert_aligned(&pairs);
    stdout
}

/// A stand-in COLMAP in `dir` (`dir/colmap`, [`fake_colmap`]) whose mapper copies the
/// prepared model `models/seed<k>` ([`ring_models`]) of its `--random_seed k`, and whose
/// refinement stages (point_filtering, bundle_adjuster) run `refine` (`$input` and `$out`
/// their folders); `prelude` runs first.
fn seeded_colmap(dir: &Path, models: &Path, prelude: &str, refine: &str) -> PathBuf {
    fake_colmap(
        dir,
        &format!(
            "{prelude}stage=$1; input=; out=; seed=\nwhile [ $# -gt 0 ]; do case \"$1\" in --input_path) input=\"$2\";; --output_path) out=\"$2\";; --random_seed) seed=\"$2\";; esac; shift; done\ncase $stage in mapper) mkdir -p \"$out/0\" && cp {}/seed$seed/* \"$out/0/\";; point_filtering|bundle_adjuster) {refine};; esac",
            models.display()
        ),
    )
}

/// The refinement of [`seeded_colmap`] that copies its input model to its output.
const COPY_INPUT: &str = "cp \"$input\"/* \"$out/\"";

/// COLMAP text models of `names` seen from a ring of cameras (radius 4, height 2), one per
/// seed under `dir/seed<k>`: seed 0 has `flipped` at its mirror place across the ring's axis,
/// seed 2 registered only the first 3 images, the others are exact in gauges of their own
/// (scaled and shifted).
fn ring_models(dir: &Path, names: &[String], flipped: &str, seeds: u64) -> PathBuf {
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

#[test]
fn train_minutes_trains_the_capture_after_structure_from_motion() {
    let _alone = alone();
    let dir = tempfile::tempdir().unwrap();
    let photos = photos(dir.path(), 8);
    let names: Vec<String> = (0..8).map(|i| format!("p{i}.png")).collect();
    let models = ring_models(dir.path(), &names, "none", 2);
    // The ring's cameras look the same way: wide-angle ones, so that they share a view.
    for seed in 0..2 {
        let cameras = models.join(format!("seed{seed}/cameras.txt"));
        std::fs::write(cameras, "1 SIMPLE_PINHOLE 8 8 2 4 4\n").unwrap();
    }
    let colmap = seeded_colmap(dir.path(), &models, "", COPY_INPUT);
    let out = dir.path().join("capture");
    let o = Command::new(env!("CARGO_BIN_EXE_nerf"))
        .args(["process", "--images"])
        .arg(&photos)
        .arg("--out")
        .arg(&out)
        .args(["--train-minutes", "0.01"])
        .env("NERF_COLMAP", &colmap)
        .output()
        .unwrap();
    let stdout = common::succeeded_stdout(&o);
    assert!(stdout.contains("8 of 8 images registered"), "{stdout}");
    assert!(stdout.contains("photos to model in"), "{stdout}");
    assert!(
        stdout.contains("view it: nerf view --config nerf_scene --checkpoint"),
        "{stdout}"
    );
    assert!(out.join("model.safetensors").is_file(), "{stdout}");
    // --view needs --train-minutes, --port needs --view: usage errors.
    for args in [&["--view"][..], &["--train-minutes", "1", "--port", "9"]] {
        let o = common::nerf(&[&["process", "--images", "x", "--out", "y"][..], args].concat());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", common::stderr(&o));
    }
}

#[test]
fn mapper_runs_keep_the_run_the_others_agree_with_and_leave_out_a_disputed_camera() {
    let _alone = alone();
    let dir = tempfile::tempdir().unwrap();
    let photos = photos(dir.path(), 8);
    let names: Vec<String> = (0..8).map(|i| format!("p{i}.png")).collect();
    let models = ring_models(dir.path(), &names, "p3.png", 4);
    // A COLMAP whose mapper copies the prepared model of its --random_seed, and whose
    // refinement stages copy their input model.
    let colmap = seeded_colmap(dir.path(), &models, "", COPY_INPUT);
    let frames_of = |out: &Path| -> Vec<String> {
        written_frames(out)
            .iter()
            .map(|f| f["file_path"].as_str().unwrap().to_string())
            .collect()
    };

    // Three runs: seed 0 flipped p3 and seed 2 registered 3 of 8, too few to compare, so a
    // fourth runs; seeds 1 and 3 agree, one of them is kept, nothing is left out, and the
    // other runs' models are gone.
    let out = dir.path().join("three");
    let o = process(&photos, &out, Some(&colmap));
    let stdout = common::succeeded_stdout(&o);
    assert!(
        stdout.contains("8 of 8 images registered;") && stdout.contains("4 mapper runs"),
        "{stdout}"
    );
    assert!(stdout.contains("train on it:"), "{stdout}");
    assert_eq!(frames_of(&out).len(), 8);
    let kept = std::fs::read_to_string(out.join("colmap/sparse/0/images.txt")).unwrap();
    assert_ne!(
        kept,
        std::fs::read_to_string(models.join("seed0/images.txt")).unwrap()
    );
    let colmap_dir = common::sorted_names(&out.join("colmap"));
    assert!(
        !colmap_dir.iter().any(|n| n.starts_with("sparse_seed")),
        "{colmap_dir:?}"
    );
    for seed in 0..4 {
        assert!(
            colmap_dir.contains(&format!("mapper_seed{seed}.log")),
            "{colmap_dir:?}"
        );
    }

    // Two runs that disagree on p3: whichever is kept, p3 is left out and named.
    let out = dir.path().join("two");
    let mut command = Command::new(env!("CARGO_BIN_EXE_nerf"));
    let o = command
        .args(["process", "--mapper-runs", "2", "--images"])
        .arg(&photos)
        .arg("--out")
        .arg(&out)
        .env("NERF_COLMAP", &colmap)
        .output()
        .unwrap();
    let stdout = common::succeeded_stdout(&o);
    assert!(
        stdout.contains("8 of 8 images registered, 1 of them left out")
            && stdout.contains("p3.png"),
        "{stdout}"
    );
    let frames = frames_of(&out);
    assert_eq!(frames.len(), 7);
    assert!(!frames.contains(&"images/p3.png".to_string()), "{frames:?}");

    // Photos on white: the hint says to train with a white background.
    let white = dir.path().join("white");
    std::fs::create_dir_all(&white).unwrap();
    for name in &names {
        image::RgbImage::from_pixel(8, 8, image::Rgb([255, 255, 255]))
            .save(white.join(name))
            .unwrap();
    }
    let out = dir.path().join("on_white");
    let o = process(&white, &out, Some(&colmap));
    let stdout = common::succeeded_stdout(&o);
    assert!(
        stdout.contains("plain white (100% of border pixels)")
            && stdout.contains("nerf train --config nerf_scene --data-dir"),
        "{stdout}"
    );

    // Bad mapping options are usage errors.
    for bad in [["--mapper-runs", "0"], ["--max-reprojection-error", "-1"]] {
        let o = common::nerf(&[&["process", "--images", "x", "--out", "y"][..], &bad[..]].concat());
        assert_eq!(o.status.code(), Some(2), "{}", common::stderr(&o));
    }
}

/// Whether ffmpeg runs here (`ffmpeg` on PATH, or `$NERF_FFMPEG`); else a visible skip, and a
/// failure under `CI=true` ([`tool_installed`]).
fn ffmpeg_installed() -> bool {
    tool_installed("ffmpeg", ("NERF_FFMPEG", "ffmpeg", "-version"), "ffmpeg")
}

/// Encodes `dir/<pattern>` (an ffmpeg image sequence, numbered from 0) at `fps` frames a
/// second into `out` (H.264 in MP4, as a phone records), with `filter` applied.
fn encode_video(dir: &Path, pattern: &str, fps: u32, filter: &str, out: &Path) {
    let program = std::env::var_os("NERF_FFMPEG").unwrap_or_else(|| "ffmpeg".into());
    let o = Command::new(program)
        .args(["-hide_banner", "-loglevel", "error", "-y", "-framerate"])
        .arg(fps.to_string())
        .args(["-start_number", "0", "-i"])
        .arg(dir.join(pattern))
        .args(["-vf", filter])
        .args(["-c:v", "libx264", "-crf", "18", "-pix_fmt", "yuv420p"])
        .arg(out)
        .output()
        .expect("run ffmpeg");
    assert!(o.status.success(), "{}", common::stderr(&o));
}

/// The grey values of the image at `path`, resized to 48×36.
fn grey_thumbnail(path: &Path) -> Vec<f32> {
    let image = image::open(path).unwrap().to_luma8();
    image::imageops::resize(&image, 48, 36, image::imageops::FilterType::Triangle)
        .pixels()
        .map(|p| f32::from(p.0[0]))
        .collect()
}

/// The index of the image in `sources` (grey thumbnails) nearest to `frame`'s by mean
/// absolute difference.
fn nearest_source(frame: &Path, sources: &[Vec<f32>]) -> usize {
    let grey = grey_thumbnail(frame);
    let distance = |s: &Vec<f32>| grey.iter().zip(s).map(|(a, b)| (a - b).abs()).sum::<f32>();
    (0..sources.len())
        .min_by(|&a, &b| distance(&sources[a]).total_cmp(&distance(&sources[b])))
        .unwrap()
}

/// `nerf process --video VIDEO --out OUT` with `extra` arguments and `env` variables.
fn process_video(video: &Path, out: &Path, extra: &[&str], env: &[(&str, &Path)]) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_nerf"));
    command
        .args(["process", "--video"])
        .arg(video)
        .arg("--out")
        .arg(out)
        .args(extra);
    for (k, v) in env {
        command.env(k, v);
    }
    command.output().expect("run nerf")
}

#[test]
fn video_frames_are_the_sharpest_of_each_stretch_and_matched_sequentially() {
    let _alone = alone();
    if !ffmpeg_installed() {
        return;
    }
    // 40 frames of a texture sliding 3 px a frame; in each run of 4, one sharp frame (at a
    // place that moves from run to run) and three blurred. At 10 fps and 10 frames kept,
    // the candidates are the clip's 40 frames and the stretches these runs of 4.
    let (dir, frames) = common::scratch("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let texture = image::RgbImage::from_fn(400, 120, |x, y| {
        let v = ((x / 6 * 7919 + y / 6 * 104_729) % 251) as u8;
        image::Rgb([v, 255 - v, v / 2])
    });
    let mut sharp = Vec::new();
    let mut sources = Vec::new();
    for i in 0..40u32 {
        let mut frame = image::imageops::crop_imm(&texture, 3 * i, 0, 160, 120).to_image();
        let is_sharp = i % 4 == (i / 4) % 4;
        if !is_sharp {
            frame = image::imageops::blur(&frame, 2.5);
        }
        let path = frames.join(format!("f_{i:03}.png"));
        frame.save(&path).unwrap();
        sharp.push(is_sharp);
        sources.push(grey_thumbnail(&path));
    }
    let video = dir.path().join("clip.mp4");
    encode_video(&frames, "f_%03d.png", 10, "null", &video);

    let names: Vec<String> = (0..10).map(|i| format!("frame_{i:05}.jpg")).collect();
    let models = ring_models(dir.path(), &names, "none", 3);
    let colmap = seeded_colmap(dir.path(), &models, "echo \"$@\"\n", COPY_INPUT);
    let tree = dir.path().join("tree.bin");
    std::fs::write(&tree, "a vocabulary tree").unwrap();
    let out = dir.path().join("capture");
    let extra = ["--frames", "10", "--vocab-tree", tree.to_str().unwrap()];
    let o = process_video(&video, &out, &extra, &[("NERF_COLMAP", &colmap)]);
    let stdout = common::succeeded_stdout(&o);
    assert!(stdout.contains("10 of 10 images registered"), "{stdout}");
    let written = common::sorted_names(&out.join("images"));
    assert_eq!(written, names);
    for name in &written {
        let source = nearest_source(&out.join("images").join(name), &sources);
        assert!(sharp[source], "{name} is frame {source}, a blurred one");
    }
    // Sequential matching, with loop detection on the given tree.
    let log = std::fs::read_to_string(out.join("colmap/sequential_matcher.log")).unwrap();
    assert!(
        log.contains("--SequentialMatching.loop_detection 1")
            && log.contains("--SequentialMatching.vocab_tree_path"),
        "{log}"
    );
    assert!(!out.join("images.partial").exists());
    assert_eq!(written_frames(&out).len(), 10);

    // A clip shorter than the frames asked for: every frame is kept, once (and a COLMAP
    // that registers nothing leaves them there, with no transforms.json).
    let idle_dir = dir.path().join("idle");
    std::fs::create_dir_all(&idle_dir).unwrap();
    let idle = fake_colmap(&idle_dir, "exit 0");
    let out = dir.path().join("all");
    let o = process_video(&video, &out, &["--frames", "60"], &[("NERF_COLMAP", &idle)]);
    let err = last_line_error(&o);
    assert!(err.contains("COLMAP registered 0 of 40 images"), "{err}");
    assert_eq!(common::sorted_names(&out.join("images")).len(), 40);
    assert!(!out.join("transforms.json").exists());
}

#[test]
fn bad_video_inputs_are_one_line_errors() {
    let _alone = alone();
    let (dir, out) = common::scratch("out");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not a video").unwrap();
    let still = dir.path().join("still.png");
    image::RgbImage::from_pixel(8, 8, image::Rgb([9, 9, 9]))
        .save(&still)
        .unwrap();
    let idle = fake_colmap(dir.path(), "exit 0");
    let colmap = [("NERF_COLMAP", idle.as_path())];

    let missing = dir.path().join("missing.mp4");
    let err = common::one_line_error(&process_video(&missing, &out, &[], &colmap));
    assert!(err.contains("missing.mp4: not a file"), "{err}");
    let nowhere = [
        ("NERF_COLMAP", idle.as_path()),
        ("NERF_FFMPEG", Path::new("/nonexistent/ffmpeg")),
    ];
    let err = common::one_line_error(&process_video(&text, &out, &[], &nowhere));
    assert!(
        err.contains("ffmpeg is missing") && err.contains("sudo apt-get install ffmpeg"),
        "{err}"
    );
    let tree = dir.path().join("no_tree.bin");
    let extra = ["--vocab-tree", tree.to_str().unwrap()];
    let err = common::one_line_error(&process_video(&text, &out, &extra, &colmap));
    assert!(err.contains("no_tree.bin: not a file"), "{err}");
    assert!(!out.exists());

    if ffmpeg_installed() {
        for file in [&text, &still] {
            let err = common::one_line_error(&process_video(file, &out, &[], &colmap));
            assert!(err.contains("not a video ffmpeg can read"), "{err}");
            assert!(!out.exists(), "{err}");
        }
    }

    // Usage errors: both sources, neither, --frames out of range or without --video.
    let v = text.to_str().unwrap();
    for args in [
        &["--images", "x", "--video", v][..],
        &[][..],
        &["--video", v, "--frames", "2"][..],
        &["--images", "x", "--frames", "10"][..],
    ] {
        let o = common::nerf(&[&["process", "--out", "y"][..], args].concat());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", common::stderr(&o));
    }
}

/// With COLMAP 3.8 this registered 13 of the 20 frames in its first full run; with COLMAP 4
/// through pycolmap, 20 of 20 in four runs of four (centres within 1.45–1.55% of the radius).
#[test]
fn colmap_recovers_lego_cameras_from_a_video() {
    let _alone = alone();
    let Some(lego) = common::lego_dir() else {
        return;
    };
    if !pycolmap_installed() || !ffmpeg_installed() {
        return;
    }
    // Lego's first 60 test views on white (a 216° arc coming down from 47° to 25° of
    // elevation) as a 10 fps clip, of which 20 frames are kept.
    let truth = lego_cameras(&lego, "test");
    let (dir, frames) = common::scratch("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let mut sources = Vec::new();
    for (i, (name, _, _)) in truth.iter().take(60).enumerate() {
        let rgba = image::open(lego.join("test").join(name))
            .unwrap()
            .to_rgba8();
        let white = image::RgbImage::from_fn(rgba.width(), rgba.height(), |x, y| {
            let p = rgba.get_pixel(x, y).0;
            let a = f32::from(p[3]) / 255.0;
            let over_white = |c: u8| (f32::from(c) * a + 255.0 * (1.0 - a)).round() as u8;
            image::Rgb([over_white(p[0]), over_white(p[1]), over_white(p[2])])
        });
        let path = frames.join(format!("v_{i:03}.png"));
        white.save(&path).unwrap();
        sources.push(grey_thumbnail(&path));
    }
    let video = dir.path().join("orbit.mp4");
    encode_video(&frames, "v_%03d.png", 10, "scale=400:400", &video);
    let out = dir.path().join("capture");
    timed_ok("--video on 60 lego test views", || {
        process_video(&video, &out, &["--frames", "20", "--sfm", "pycolmap"], &[])
    });

    let frames = written_frames(&out);
    assert!(frames.len() >= 15, "{} of 20 registered", frames.len());
    let pairs: Vec<CameraPair> = frames
        .iter()
        .map(|f| {
            let path = f["file_path"].as_str().unwrap();
            let source = nearest_source(&out.join(path), &sources);
            let (_, true_rotation, true_centre) = truth[source].clone();
            let (rotation, centre) = rotation_and_centre(&f["transform_matrix"]);
            CameraPair {
                true_rotation,
                true_centre,
                rotation,
                centre,
            }
        })
        .collect();
    assert_aligned(&pairs);
}
