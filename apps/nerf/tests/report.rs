//! `nerf report`: the quick report's measurements, markdown, JSON and plots, and its one-line
//! errors.

mod common;

use std::path::Path;

use common::{nerf, nerf_in, nerf_ok, stderr};

/// `nerf report --quick --out-dir OUT MORE…`.
fn quick_report_args<'a>(out: &'a Path, more: &[&'a str]) -> Vec<&'a str> {
    [
        &["report", "--quick", "--out-dir", out.to_str().unwrap()][..],
        more,
    ]
    .concat()
}

#[test]
fn report_quick_measures_and_writes_markdown_json_and_plots() {
    let root = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."));
    let data = root.join("../shared/data/lego");
    let (dir, out) = common::scratch("report");
    let missing_log = dir.path().join("no_such.log.jsonl");
    let checkpoint = root.join("checkpoints/nerf_lego.safetensors");
    let shipped_log = root.join("checkpoints/nerf_lego.log.jsonl");
    let mut args = quick_report_args(
        &out,
        &[
            "--log",
            shipped_log.to_str().unwrap(),
            "--log",
            missing_log.to_str().unwrap(),
        ],
    );
    if data.is_dir() {
        args.extend([
            "--views",
            "1",
            "--data-dir",
            data.to_str().unwrap(),
            "--checkpoint",
            checkpoint.to_str().unwrap(),
        ]);
    } else {
        args.push("--no-lego");
    }
    nerf_ok(&args);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();

    // Box: the hard box converges to the analytic surface; every number is finite.
    let rows = json["hard_box"]["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 6, "8 … 256 samples per ray");
    let depth_err = |r: &serde_json::Value| r["vs_analytic"]["depth_mae"].as_f64().unwrap();
    let first = depth_err(&rows[0]);
    let last = depth_err(rows.last().unwrap());
    assert!(last < first / 10.0, "depth error {first} -> {last}");
    assert!(last < 5.0 / 256.0, "below one sample spacing: {last}");
    for study in ["hard_box", "homework_box"] {
        for r in json[study]["rows"].as_array().unwrap() {
            assert!(r["seconds_per_frame"].as_f64().unwrap() > 0.0);
            assert!(r["vs_reference"]["color_rmse"]
                .as_f64()
                .unwrap()
                .is_finite());
        }
    }
    for png in ["box_error_vs_time.png", "training_psnr_vs_time.png"] {
        let img = image::open(out.join(png)).unwrap();
        assert_eq!((img.width(), img.height()), (900, 560), "{png}");
        assert!(
            md.contains(&format!("]({png})")),
            "{png} linked from report.md"
        );
    }
    // Each table states machine, profile and threads.
    assert!(md.matches("Machine: ").count() >= 3, "{md}");
    assert!(md.contains("threads") && md.contains("release build"));

    // Training: the shipped log's test PSNR curve, and a clear note for the missing log.
    let training = json["training"].as_array().unwrap();
    let test = training[0]["Ok"]["test"].as_array().unwrap();
    assert!(test.len() >= 10, "{} evaluations", test.len());
    assert!(training[1]["Err"]
        .as_str()
        .unwrap()
        .contains("no_such.log.jsonl"));
    assert!(md.contains("Skipped a training log"));

    // Lego (where the data is): every acceleration at 32 and 128 samples per ray.
    if data.is_dir() {
        let lego = json["lego"]["Ok"]["rows"].as_array().unwrap();
        // Four accelerations of the MLP and coarse-to-fine at two sample counts, and the
        // shipped hash-grid model at both counts.
        let hash = "hash grid (grid + early termination)";
        let shipped_ngp = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
            .join("checkpoints/ngp_lego.safetensors")
            .is_file();
        let rows_of = |name: &str| lego.iter().filter(|r| r["acceleration"] == name).count();
        let hash_rows = rows_of(hash);
        assert_eq!(lego.len() - hash_rows, 10);
        assert_eq!(rows_of("coarse-to-fine (n/2 coarse + n/2 fine)"), 2);
        assert_eq!(hash_rows, if shipped_ngp { 2 } else { 0 });
        for r in lego {
            let psnr = r["psnr_vs_truth"].as_f64().unwrap();
            assert!((15.0..40.0).contains(&psnr), "{r}");
            if r["acceleration"] == "grid + early termination" {
                assert!(r["evaluated"].as_f64().unwrap() < 0.2, "{r}");
            }
        }
        assert!(out.join("lego_psnr_vs_time.png").is_file());
    } else {
        eprintln!("lego section left out: no data at {}", data.display());
        assert_eq!(json["lego"]["Err"], "left out (--no-lego)");
    }
    // The load average is measured and stated, not assumed.
    assert!(md.contains("load average"), "{md}");
    assert!(!md.contains("nothing else running"), "{md}");
    // Nothing half-written.
    for entry in std::fs::read_dir(&out).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().to_string();
        assert!(!name.ends_with(".tmp"), "{name}");
    }
}

#[test]
fn report_rejects_an_unusable_output_directory_in_one_line() {
    let (_dir, file) = common::scratch("a_file");
    std::fs::write(&file, b"x").unwrap();
    let o = nerf(&quick_report_args(&file.join("sub"), &["--no-lego"]));
    let err = common::one_line_error(&o);
    assert!(err.contains("a_file"), "{err}");
}

#[test]
fn report_without_its_lego_inputs_is_one_line_naming_them_and_writes_nothing() {
    let (dir, out) = common::scratch("report");
    // Run from an empty directory, as a user outside the repository would: the default
    // checkpoint and dataset paths are relative and missing there.
    let o = nerf_in(dir.path(), &quick_report_args(&out, &[]));
    let err = common::one_line_error(&o);
    assert!(err.contains("relative to the working directory"), "{err}");
    assert!(err.contains("--no-lego"), "{err}");
    assert!(!out.exists(), "nothing written before the check");
    // A missing dataset with a present checkpoint names the dataset.
    let checkpoint = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("checkpoints/nerf_lego.safetensors");
    let missing = dir.path().join("no_data");
    let o = nerf(&quick_report_args(
        &out,
        &[
            "--checkpoint",
            checkpoint.to_str().unwrap(),
            "--data-dir",
            missing.to_str().unwrap(),
        ],
    ));
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no_data") && err.contains("transforms_test.json"),
        "{err}"
    );
    assert!(!out.exists());
}
