//! Sizes inside the limits: jobs work through images, sample sets and grids in bounded pieces
//! whose size does not change any output (forced down to a few items with `NERF_WORK_CHUNK`
//! and a tiny `renderer.chunk_size`), and what is over a limit, or fails, leaves no outputs.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

mod common;
use common::{export_args, lego_scratch, render_args, stderr};

/// Runs the `nerf` binary with `args`, with `NERF_WORK_CHUNK` set to `chunk` (or unset).
fn nerf_chunked(chunk: Option<&str>, args: &[&str]) -> Output {
    let mut command = common::nerf_command();
    command.args(args).env_remove("NERF_WORK_CHUNK");
    if let Some(c) = chunk {
        command.env("NERF_WORK_CHUNK", c);
    }
    command.output().expect("run nerf")
}

/// Every file of `dir` by name, with its bytes.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().to_string(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect()
}

/// Asserts `o` failed with one `error: ` line containing `expect`.
fn refused_with(o: &Output, expect: &str) {
    let err = stderr(o);
    assert!(!o.status.success(), "succeeded: {err}");
    let errors: Vec<&str> = err.lines().filter(|l| !l.starts_with("loaded ")).collect();
    assert_eq!(errors.len(), 1, "{err}");
    assert!(
        errors[0].starts_with("error: ") && errors[0].contains(expect),
        "{err}"
    );
}

/// Asserts that `nerf export KIND --config CONFIG EXTRA… --out OUT` is refused (as
/// [`refused_with`] says) and leaves nothing at `out`.
fn refused_export(kind: &str, config: &str, extra: &[&str], out: &Path, expect: &str) {
    let o = nerf_chunked(
        None,
        &export_args(kind, config, extra, out.to_str().unwrap()),
    );
    refused_with(&o, expect);
    assert!(!out.exists());
}

#[test]
fn a_render_in_tiny_pieces_equals_the_render_in_one() {
    let dir = tempfile::tempdir().unwrap();
    let render = |chunk: Option<&str>, name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let small = ["--raw", "data.image_size=[37,23]", "cameras.n_poses=3"];
        let mut args = render_args("box", &out, &small);
        args.extend(extra);
        let o = nerf_chunked(chunk, &args);
        assert!(o.status.success(), "{}", stderr(&o));
        files(&out)
    };
    // Pieces far larger than the image: everything at once.
    let whole = render(
        Some("1000000000"),
        "whole",
        &["renderer.chunk_size=1000000"],
    );
    let default = render(None, "default", &[]);
    // 5 rays per band and 5 sample points per pass, in renderer chunks of 3 rays.
    let tiny = render(Some("5"), "tiny", &["renderer.chunk_size=3"]);
    let names: Vec<&str> = whole.keys().map(String::as_str).collect();
    for expected in [
        "grid_vis.png",
        "ray_vis.png",
        "point_vis.png",
        "depth.png",
        "render_cube.gif",
        "color_002.npy",
        "depth_002.npy",
    ] {
        assert!(names.contains(&expected), "{names:?}");
    }
    assert_eq!(default, whole, "default pieces");
    for (name, bytes) in &whole {
        assert!(tiny[name] == *bytes, "{name} differs in tiny pieces");
    }
    assert_eq!(tiny.len(), whole.len());
}

#[test]
fn a_mesh_and_a_point_cloud_in_tiny_pieces_equal_them_in_one() {
    let dir = tempfile::tempdir().unwrap();
    let run = |chunk: Option<&str>, args: &[&str]| {
        let o = nerf_chunked(chunk, args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    };
    for (chunk, renderer_chunk) in [
        ("1000000000", "renderer.chunk_size=1000000"),
        ("7", "renderer.chunk_size=3"),
    ] {
        let mesh = dir.path().join(format!("mesh_{chunk}.ply"));
        run(
            Some(chunk),
            &export_args(
                "mesh",
                "sphere",
                &["--resolution", "24", renderer_chunk],
                mesh.to_str().unwrap(),
            ),
        );
        let points = dir.path().join(format!("points_{chunk}.ply"));
        run(
            Some(chunk),
            &export_args(
                "points",
                "box",
                &["--limit", "2", "data.image_size=[29,17]", renderer_chunk],
                points.to_str().unwrap(),
            ),
        );
    }
    for kind in ["mesh", "points"] {
        let read =
            |chunk: &str| std::fs::read(dir.path().join(format!("{kind}_{chunk}.ply"))).unwrap();
        let (whole, tiny) = (read("1000000000"), read("7"));
        assert!(whole.len() > 1000, "{kind}: {} bytes", whole.len());
        assert!(whole == tiny, "{kind} differs in tiny pieces");
    }
}

#[test]
fn sizes_over_a_limit_and_bad_pieces_are_refused_before_anything_is_written() {
    let (dir, out) = common::scratch("out");
    // (NERF_WORK_CHUNK, overrides, what the refusal says) of a box render.
    let too_large: [(Option<&str>, &[&str], &str); 2] = [
        (
            None,
            &["data.image_size=[4097,8]"],
            "data.image_size: width and height must be 1 to 4096",
        ),
        (
            None,
            &["cameras.n_poses=5", "data.image_size=[4096,4096]"],
            "pixels in all",
        ),
    ];
    let bad_pieces = ["0", "many", "-3"].map(|bad| -> (Option<&str>, &[&str], &str) {
        (
            Some(bad),
            &[],
            "NERF_WORK_CHUNK: must be a whole number of at least 1",
        )
    });
    for (chunk, overrides, expect) in too_large.into_iter().chain(bad_pieces) {
        let o = nerf_chunked(chunk, &render_args("box", &out, overrides));
        refused_with(&o, expect);
        assert!(!out.exists());
    }
    refused_export(
        "mesh",
        "sphere",
        &["--resolution", "513"],
        &dir.path().join("m.ply"),
        "--resolution must be 1 to 512",
    );
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn a_point_cloud_of_more_rays_than_its_limit_is_refused_before_rendering() {
    let Some((data, dir)) = lego_scratch() else {
        return;
    };
    // 100 training views of 2048² pixels: 419M rays, over 2^27.
    refused_export(
        "points",
        "lego",
        &[
            "--data-dir",
            data.to_str().unwrap(),
            "data.image_size=[2048,2048]",
            "cameras.n_poses=1",
        ],
        &dir.path().join("p.ply"),
        "over the 134217728 a point cloud may have",
    );
}

#[test]
fn a_render_whose_last_file_cannot_be_written_leaves_none_of_its_files() {
    let dir = tempfile::tempdir().unwrap();
    // A directory where the GIF goes: the PNGs are written first, then the GIF fails.
    std::fs::create_dir(dir.path().join("render_cube.gif")).unwrap();
    let o = nerf_chunked(
        None,
        &render_args(
            "box",
            dir.path(),
            &["data.image_size=[16,16]", "cameras.n_poses=3"],
        ),
    );
    refused_with(&o, "render_cube.gif");
    let left: Vec<String> = common::sorted_names(dir.path());
    assert_eq!(left, vec!["render_cube.gif".to_string()]);
}
