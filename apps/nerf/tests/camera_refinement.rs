//! Camera refinement (`training.camera_refinement`) on a capture whose cameras are off: lego
//! views written as a COLMAP model, the training cameras each turned by 1° about a random
//! axis and moved by 1% of the cameras' radius, the held-out cameras exact. Trained with
//! `nerf_scene` on the exact cameras, on the perturbed ones without refinement and on the
//! perturbed ones with it, and scored on the held-out views: the refined run must win back
//! most of what the perturbation lost.
//!
//! The sizes are CI's by default (32 views at 48×48, 10 epochs of 8192 samples a step);
//! `CAMERA_REFINEMENT_VIEWS`, `CAMERA_REFINEMENT_SIZE`, `CAMERA_REFINEMENT_EPOCHS` and
//! `CAMERA_REFINEMENT_SAMPLES` (`training.samples_per_step`) make it the measurement of
//! docs/own-scene.md (run with `--nocapture` to see the scores), and
//! `CAMERA_REFINEMENT_EXACT=1` adds a fourth run, the exact cameras refined.

mod common;

use std::path::Path;

use common::lego_capture::*;

fn env_or(key: &str, default: usize) -> usize {
    std::env::var(key)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Trains `nerf_scene` on `capture` with `overrides` and returns the held-out views' mean
/// PSNR, and the training's stderr.
fn train_and_score(capture: &Path, checkpoint: &Path, overrides: &[String]) -> (f64, String) {
    let dir = capture.to_str().unwrap();
    let ckpt = format!("training.checkpoint_path={}", checkpoint.display());
    let mut args: Vec<&str> = vec!["train", "--config", "nerf_scene", "--data-dir", dir];
    args.push(&ckpt);
    args.extend(overrides.iter().map(String::as_str));
    let started = std::time::Instant::now();
    let trained = common::nerf_ok(&args);
    let seconds = started.elapsed().as_secs_f64();
    args[0] = "eval";
    args.extend(["--split", "test", "--json"]);
    let o = common::nerf_ok(&args);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let psnr = report["mean_psnr"].as_f64().unwrap();
    eprintln!(
        "{} {:?}: {psnr:.2} dB on {} held-out views ({seconds:.0} s)",
        capture.file_name().unwrap().to_string_lossy(),
        overrides.last().unwrap(),
        report["views"].as_array().unwrap().len()
    );
    (psnr, common::stderr(&trained))
}

#[test]
#[ignore = "at CI's size on today's nerf_scene the perturbation costs too little to read a \
            recovery (exact 21.31, perturbed 20.77, refined 20.92 dB); run with \
            CAMERA_REFINEMENT_VIEWS=100 and a larger CAMERA_REFINEMENT_SIZE (issue 29)"]
fn refined_cameras_recover_most_of_the_psnr_that_perturbed_cameras_lose() {
    let views = env_or("CAMERA_REFINEMENT_VIEWS", 32).min(100);
    let Some(lego) = lego_views(views) else {
        return;
    };
    let size = env_or("CAMERA_REFINEMENT_SIZE", 48);
    let epochs = env_or("CAMERA_REFINEMENT_EPOCHS", 10);
    let samples = env_or("CAMERA_REFINEMENT_SAMPLES", 8192);
    let root = tempfile::tempdir().unwrap();
    let exact = root.path().join("exact");
    let perturbed = root.path().join("perturbed");
    write_colmap_text(&lego, &exact);
    write_colmap_text(&lego.perturbed(1.0, 0.01, 7), &perturbed);
    let common = vec![
        format!("data.image_size=[{size},{size}]"),
        format!("training.num_epochs={epochs}"),
        "training.eval_views=0".to_string(),
        format!("training.samples_per_step={samples}"),
        // The photos' alpha composited on black and trained on black: a random background
        // per step (what `auto` does for photos with alpha) needs more than these few hundred
        // steps to leave its grey veil, which would hide what the cameras do.
        "renderer.background=black".to_string(),
    ];
    let run = |capture: &Path, name: &str, mode: &str| {
        let mut o = common.clone();
        o.push(format!("training.camera_refinement={mode}"));
        train_and_score(capture, &root.path().join(name), &o)
    };
    let (exact_psnr, _) = run(&exact, "exact.safetensors", "off");
    let (lost_psnr, _) = run(&perturbed, "perturbed.safetensors", "off");
    let (refined_psnr, log) = run(&perturbed, "refined.safetensors", "on");
    assert!(log.contains("refining the"), "{log}");
    let refined_cameras = root.path().join("refined.cameras.json");
    let cameras: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&refined_cameras).unwrap()).unwrap();
    let cameras = cameras["cameras"].as_array().unwrap();
    assert_eq!(cameras.len(), views - views.div_ceil(8));
    let mean_turn = cameras
        .iter()
        .map(|c| c["rotation_degrees"].as_f64().unwrap())
        .sum::<f64>()
        / cameras.len() as f64;
    eprintln!(
        "exact {exact_psnr:.2} dB, perturbed {lost_psnr:.2} dB, refined {refined_psnr:.2} dB; \
         mean refined turn {mean_turn:.2}°"
    );
    // The perturbation costs a clear loss, and the refinement wins back most of it.
    let lost = exact_psnr - lost_psnr;
    assert!(lost > 1.0, "the perturbation cost only {lost:.2} dB");
    let recovered = refined_psnr - lost_psnr;
    assert!(
        recovered > 0.5 * lost,
        "refinement recovered {recovered:.2} of {lost:.2} dB"
    );
    // No run wrote refined cameras where none were refined.
    assert!(!root.path().join("exact.cameras.json").exists());
    if env_or("CAMERA_REFINEMENT_EXACT", 0) == 1 {
        // The measurement's fourth run: refinement on the exact cameras.
        let (psnr, _) = run(&exact, "exact_refined.safetensors", "on");
        eprintln!("exact cameras refined: {psnr:.2} dB (not refined: {exact_psnr:.2} dB)");
    }
}
