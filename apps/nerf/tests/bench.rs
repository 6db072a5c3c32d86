//! `nerf bench --quick`: every row it prints, and the throughput of the matrix-multiply and
//! hash-grid rows (no timing thresholds: only that each number is there, positive and finite).

mod common;

use std::path::Path;

use common::{lego_dir, nerf_ok};

/// The rows of `report` whose name starts with `prefix`.
fn rows<'a>(report: &'a serde_json::Value, prefix: &str) -> Vec<&'a serde_json::Value> {
    report["results"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["name"].as_str().unwrap().starts_with(prefix))
        .collect()
}

/// `row.throughput.key` as a positive, finite number.
fn positive(row: &serde_json::Value, key: &str) -> f64 {
    let v = row["throughput"][key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing: {row}"));
    assert!(v.is_finite() && v > 0.0, "{key} = {v}: {row}");
    v
}

#[test]
fn bench_quick_has_matmul_and_hash_grid_rows_with_positive_rates() {
    let o = nerf_ok(&["bench", "--config", "box", "--quick", "--json"]);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for r in report["results"].as_array().unwrap() {
        let s = r["seconds"].as_f64().unwrap();
        assert!(s.is_finite() && s > 0.0, "{r}");
    }
    // Quick: no whole-command rows.
    assert!(rows(&report, "box command").is_empty());
    let matmul = rows(&report, "f32 matmul");
    assert_eq!(matmul.len(), 3, "{report}");
    for r in &matmul {
        positive(r, "gflops");
    }
    // The memory rows: one level's table and all 16 levels' (rates only: no timing asserted).
    let reads = rows(&report, "random row reads");
    assert_eq!(reads.len(), 2, "{report}");
    assert!(reads[0]["name"].as_str().unwrap().contains("2 MiB"));
    assert!(reads[1]["name"].as_str().unwrap().contains("32 MiB"));
    for r in &reads {
        positive(r, "row_reads_per_second");
    }
    let Some(_) = lego_dir() else {
        return;
    };
    let training = rows(&report, "hash-grid training");
    assert_eq!(training.len(), 2, "{report}");
    assert!(training[0]["name"].as_str().unwrap().contains("16384"));
    assert!(training[1]["name"].as_str().unwrap().contains("262144"));
    let mut hash_grid = training;
    let checkpoint = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("checkpoints/ngp_lego_400.safetensors");
    if checkpoint.is_file() {
        let render = rows(&report, "hash-grid render 400x400");
        assert_eq!(render.len(), 1, "{report}");
        hash_grid.extend(render);
    }
    for r in hash_grid {
        let evaluated = positive(r, "evaluated_samples_per_second");
        let drawn = positive(r, "drawn_samples_per_second");
        assert!(evaluated <= drawn, "{r}");
        positive(r, "rays_per_second");
        positive(r, "flop_per_evaluated_sample");
        positive(r, "gflops");
        positive(r, "fraction_of_mlp_gemm");
        positive(r, "fraction_of_square_gemm");
    }
}

#[test]
fn bench_only_runs_the_groups_asked_for() {
    let o = nerf_ok(&[
        "bench", "--config", "box", "--quick", "--json", "--only", "matmul",
    ]);
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let names: Vec<&str> = report["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["name"].as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 3, "{names:?}");
    assert!(
        names.iter().all(|n| n.starts_with("f32 matmul")),
        "{names:?}"
    );
    let o = common::nerf(&["bench", "--config", "box", "--only", "no-such-rows"]);
    assert_eq!(o.status.code(), Some(2));
}
