//! `nerf export`: meshes, point clouds and depth maps, read back and checked against what the
//! scene is known to hold.

use std::path::Path;

use nerf::io::dataset::{load_image_and_transparency, read_split, Split};
use nerf::PerspectiveCamera;

mod common;
use common::{export_args, lego_scratch, nerf, nerf_ok, read_npy, render_args, stderr};

/// A binary PLY as `nerf export` writes it: vertices (x, y, z[, nx, ny, nz], r, g, b) and
/// triangles. The header must be exactly the layout written, or the test fails.
struct Ply {
    vertices: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    colors: Vec<[u8; 3]>,
    faces: Vec<[u32; 3]>,
}

fn read_ply(path: &Path) -> Ply {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    let count = |element: &str| -> usize {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("element {element} ")))
            .map_or(0, |n| n.parse().unwrap())
    };
    let (n_vertices, n_faces) = (count("vertex"), count("face"));
    let with_normals = header.contains("property float nx\n");
    let floats = if with_normals { 6 } else { 3 };
    let mut at = end;
    let f32_at = |at: &mut usize| {
        let v = f32::from_le_bytes(bytes[*at..*at + 4].try_into().unwrap());
        *at += 4;
        v
    };
    let mut ply = Ply {
        vertices: vec![],
        normals: vec![],
        colors: vec![],
        faces: vec![],
    };
    for _ in 0..n_vertices {
        let v: Vec<f32> = (0..floats).map(|_| f32_at(&mut at)).collect();
        ply.vertices.push([v[0], v[1], v[2]]);
        if with_normals {
            ply.normals.push([v[3], v[4], v[5]]);
        }
        ply.colors.push([bytes[at], bytes[at + 1], bytes[at + 2]]);
        at += 3;
    }
    for _ in 0..n_faces {
        assert_eq!(bytes[at], 3);
        let idx = |k: usize| {
            i32::from_le_bytes(bytes[at + 1 + 4 * k..at + 5 + 4 * k].try_into().unwrap())
        };
        ply.faces.push([0, 1, 2].map(|k| idx(k) as u32));
        at += 13;
    }
    assert_eq!(at, bytes.len(), "trailing bytes after the last element");
    ply
}

/// The mesh seen by `camera` on the homework's pixel grid (`x_ndc = 1 − 2c/(W−1)`,
/// `y_ndc = 1 − 2r/(H−1)`), z-buffered: per pixel the nearest triangle's vertex colours
/// interpolated, or `None` where no triangle with all corners in front of the camera covers the
/// pixel centre.
fn rasterize(ply: &Ply, camera: &PerspectiveCamera, w: usize, h: usize) -> Vec<Option<[f64; 3]>> {
    let projected: Vec<Option<[f64; 3]>> = ply
        .vertices
        .iter()
        .map(|v| {
            let p = camera.project(glam::DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
            let (c, r) = (
                (1.0 - p.x) * (w - 1) as f64 / 2.0,
                (1.0 - p.y) * (h - 1) as f64 / 2.0,
            );
            (p.z > 0.0).then_some([c, r, p.z])
        })
        .collect();
    let mut depth = vec![f64::INFINITY; w * h];
    let mut image = vec![None; w * h];
    for f in &ply.faces {
        let [Some(a), Some(b), Some(c)] = f.map(|i| projected[i as usize]) else {
            continue;
        };
        let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        if area == 0.0 {
            continue;
        }
        let lo = |k: usize| a[k].min(b[k]).min(c[k]).ceil().max(0.0) as i64;
        let hi = |k: usize, n: usize| (a[k].max(b[k]).max(c[k]).floor() as i64).min(n as i64 - 1);
        for r in lo(1)..=hi(1, h) {
            for col in lo(0)..=hi(0, w) {
                let (x, y) = (col as f64, r as f64);
                let edge = |p: [f64; 3], q: [f64; 3]| {
                    ((q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0])) / area
                };
                // Barycentric weights of a, b, c.
                let l = [edge(b, c), edge(c, a), edge(a, b)];
                let i = r as usize * w + col as usize;
                let z = l[0] * a[2] + l[1] * b[2] + l[2] * c[2];
                if l.iter().all(|v| *v >= 0.0) && z < depth[i] {
                    depth[i] = z;
                    let rgb = f.map(|v| ply.colors[v as usize]);
                    image[i] = Some(std::array::from_fn(|k| {
                        (0..3).map(|j| l[j] * rgb[j][k] as f64).sum::<f64>() / 255.0
                    }));
                }
            }
        }
    }
    image
}

/// `nerf export mesh` of `config` at `resolution` into `out`.
fn mesh_args<'a>(config: &'a str, resolution: &'a str, out: &'a str) -> Vec<&'a str> {
    export_args("mesh", config, &["--resolution", resolution], out)
}

fn iou(a: &[bool], b: &[bool]) -> f64 {
    let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
    inter as f64 / union.max(1) as f64
}

#[test]
fn lego_mesh_covers_the_test_masks() {
    let Some((lego, dir)) = lego_scratch() else {
        return;
    };
    let out = dir.path().join("lego.ply");
    nerf_ok(&mesh_args("lego", "128", out.to_str().unwrap()));
    let ply = read_ply(&out);
    assert!(ply.faces.len() > 10_000, "{} faces", ply.faces.len());
    // Every 10th test view at 100×100 against alpha > 0.5.
    let frames = read_split(&lego, Split::Test).unwrap();
    let (w, h) = (100, 100);
    let mut scores = Vec::new();
    for frame in frames.iter().step_by(10) {
        let (_, transparency) = load_image_and_transparency(&frame.file_path, w, h, false).unwrap();
        let truth: Vec<bool> = transparency.iter().map(|t| 1.0 - t > 0.5).collect();
        let seen = rasterize(&ply, frame.camera.pinhole().unwrap(), w, h);
        let mask: Vec<bool> = seen.iter().map(Option::is_some).collect();
        scores.push(iou(&mask, &truth));
        // For a person to look at: NERF_TEST_MESH_VIEWS=DIR writes each view of the mesh,
        // rasterised at 256×256.
        if let Ok(views) = std::env::var("NERF_TEST_MESH_VIEWS") {
            let big = rasterize(&ply, frame.camera.pinhole().unwrap(), 256, 256);
            let bytes: Vec<u8> = big
                .iter()
                .flat_map(|p| p.unwrap_or([0.0; 3]).map(|v| (v * 255.0) as u8))
                .collect();
            let name = frame
                .file_path
                .file_stem()
                .unwrap()
                .to_string_lossy()
                .to_string();
            image::RgbImage::from_raw(256, 256, bytes)
                .unwrap()
                .save(Path::new(&views).join(format!("mesh_{name}.png")))
                .unwrap();
        }
    }
    let mean = scores.iter().sum::<f64>() / scores.len() as f64;
    let worst = scores.iter().cloned().fold(1.0, f64::min);
    eprintln!(
        "lego mesh: {} vertices, {} faces; silhouette IoU over {} test views: mean {mean:.4}, min {worst:.4}",
        ply.vertices.len(),
        ply.faces.len(),
        scores.len()
    );
    assert!(mean > 0.9 && worst > 0.8, "IoU mean {mean}, min {worst}");
}

#[test]
fn sphere_mesh_lies_on_the_radius_with_its_rainbow_colours() {
    let (_dir, out) = common::scratch("sphere.ply");
    nerf_ok(&mesh_args("sphere", "48", out.to_str().unwrap()));
    let ply = read_ply(&out);
    assert!(!ply.vertices.is_empty() && !ply.faces.is_empty());
    // The sphere config: radius 1 at the origin; the box is ±(1 + 0.1 + 4·0.05) = ±1.3, so a
    // cell is 2.6/48 ≈ 0.054 and vertices sit within a fraction of it of the radius.
    for (v, n) in ply.vertices.iter().zip(&ply.normals) {
        let r = v.iter().map(|c| c * c).sum::<f32>().sqrt();
        assert!((r - 1.0).abs() < 0.01, "vertex at radius {r}");
        let radial: f32 = n.iter().zip(v).map(|(a, b)| a * b).sum::<f32>() / r;
        assert!(radial > 0.95, "normal {n:?} at {v:?}");
    }
    // Rainbow colouring: |p − centre| clamped to [0.02, 0.98], seen just outside the surface.
    for (v, c) in ply.vertices.iter().zip(&ply.colors) {
        for k in 0..3 {
            let expected = v[k].abs().clamp(0.02, 0.98);
            assert!(
                (c[k] as f32 / 255.0 - expected).abs() < 0.05,
                "colour {c:?} at {v:?}"
            );
        }
    }
}

#[test]
fn points_and_depth_export_the_box_views() {
    let (dir, ply_path) = common::scratch("box_points.ply");
    // `nerf export KIND` of the first `limit` box views, small, into `out`.
    let export_box = |kind: &str, limit: &str, out: &Path| {
        let mut args = export_args(kind, "box", &["--limit", limit], out.to_str().unwrap());
        args.extend(["data.image_size=[32,24]", "sampler.n_pts_per_ray=32"]);
        nerf_ok(&args);
    };
    export_box("points", "3", &ply_path);
    let ply = read_ply(&ply_path);
    assert!(ply.faces.is_empty() && ply.normals.is_empty());
    assert!(ply.vertices.len() > 100, "{} points", ply.vertices.len());
    // The box has sides 1.75: expected-depth points lie near its surface (within the soft
    // edge's blur, β = 0.05, and one sample step of 5/31).
    for p in &ply.vertices {
        let linf = p.iter().fold(0.0f32, |a, b| a.max(b.abs()));
        assert!(
            (linf - 0.875).abs() < 0.2,
            "point {p:?} is {linf} from the centre"
        );
    }
    let depth_dir = dir.path().join("depth");
    export_box("depth", "2", &depth_dir);
    for name in ["view_000", "view_001"] {
        let (shape, depth) = read_npy(&depth_dir.join(format!("{name}.npy")));
        assert_eq!(shape, vec![24, 32]);
        // The centre pixel sees the box's face at 3 − 0.875.
        let centre = depth[12 * 32 + 16];
        assert!(
            (centre - 2.125).abs() < 0.2,
            "{name}: centre depth {centre}"
        );
        let png = image::open(depth_dir.join(format!("{name}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (32, 24));
    }
    assert!(!depth_dir.join("view_002.npy").exists());
}

/// Runs `nerf` expecting a one-line error and no file at `out`.
fn refused(args: &[&str], out: &Path, expect: &str) {
    let o = nerf(args);
    let err = stderr(&o);
    assert!(!o.status.success(), "{args:?} succeeded");
    // One error line (after the `loaded FILE …` line of a command that loaded a model).
    let errors: Vec<&str> = err.lines().filter(|l| !l.starts_with("loaded ")).collect();
    assert_eq!(errors.len(), 1, "{args:?}: {err}");
    assert!(
        errors[0].starts_with("error: ") && err.contains(expect),
        "{args:?}: {err}"
    );
    assert!(!out.exists(), "{args:?} left {}", out.display());
}

#[test]
fn export_refuses_bad_input_in_one_line_and_writes_nothing() {
    let (dir, out) = common::scratch("m.ply");
    let o = out.to_str().unwrap();
    refused(
        &mesh_args("sphere", "0", o),
        &out,
        "--resolution must be 1 to 512",
    );
    refused(
        &mesh_args("sphere", "100000", o),
        &out,
        "--resolution must be 1 to 512",
    );
    let missing_checkpoint = ["--checkpoint", "/nonexistent/x.safetensors"];
    refused(
        &export_args("mesh", "lego", &missing_checkpoint, o),
        &out,
        "not found",
    );
    for (threshold, expect) in [("2", "threshold"), ("nan", "finite")] {
        refused(
            &export_args("mesh", "sphere", &["--threshold", threshold], o),
            &out,
            expect,
        );
    }
    // A directory that cannot exist: its parent is a file.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let inside = blocker.join("m.ply");
    for (kind, config) in [("mesh", "sphere"), ("points", "box")] {
        refused(
            &export_args(kind, config, &[], inside.to_str().unwrap()),
            &inside,
            "cannot create output directory",
        );
    }
    // No surface at all: the lego NeRF's density never reaches 1e9.
    let unreachable = ["--resolution", "16", "--threshold", "1e9"];
    refused(
        &export_args("mesh", "lego", &unreachable, o),
        &out,
        "no surface at threshold",
    );
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        1,
        "only the blocker file is left"
    );
}

/// Overrides that make `nerf_lego_ngp` tiny: 16×16 images, a 4-level 2^10 table.
const TINY_NGP: [&str; 7] = [
    "data.image_size=[16,16]",
    "sampler.n_pts_per_ray=16",
    "training.eval_views=0",
    "renderer.occupancy_grid.resolution=8",
    "implicit_function.n_levels=4",
    "implicit_function.log2_hashmap_size=10",
    "implicit_function.max_resolution=32",
];

#[test]
fn ngp_trains_for_minutes_then_exports_a_half_precision_model_that_evaluates_the_same() {
    let Some((data, dir)) = lego_scratch() else {
        return;
    };
    let ckpt = dir.path().join("ngp.safetensors");
    let ckpt_key = format!("training.checkpoint_path={}", ckpt.display());
    let with = |head: &[&str]| -> Vec<String> {
        head.iter()
            .map(|s| s.to_string())
            .chain(TINY_NGP.iter().map(|s| s.to_string()))
            .chain([ckpt_key.clone()])
            .collect()
    };
    let run = |args: &[String]| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = nerf(&args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let data_arg = data.to_str().unwrap();
    let out = run(&with(&[
        "train",
        "--config",
        "nerf_lego_ngp",
        "--data-dir",
        data_arg,
        "--minutes",
        "0.05",
    ]));
    // Three seconds of training end in whichever epoch this machine's speed reaches, in a
    // checkpoint that says where: "trained to epoch N step K" mid-epoch, or "trained to epoch
    // N (…)" when the limit falls on an epoch's end (seen once in a full suite run, at epoch
    // 1 after 100 steps).
    assert!(
        out.lines().any(|l| l.contains("trained to epoch ")),
        "{out}"
    );
    let model = dir.path().join("model.safetensors");
    let out = run(&with(&export_args(
        "model",
        "nerf_lego_ngp",
        &[],
        model.to_str().unwrap(),
    )));
    assert!(out.contains("largest f16 rounding"), "{out}");
    let (full, _) = nerf::io::checkpoint::load(&ckpt, &candle_core::Device::Cpu).unwrap();
    let (slim, _) = nerf::io::checkpoint::load(&model, &candle_core::Device::Cpu).unwrap();
    assert!(full.keys().any(|k| k.starts_with("adam.")));
    assert!(!slim.keys().any(|k| k.starts_with("adam.")));
    assert_eq!(
        slim.len(),
        full.keys().filter(|k| !k.starts_with("adam.")).count()
    );
    assert!(std::fs::metadata(&model).unwrap().len() * 3 < std::fs::metadata(&ckpt).unwrap().len());
    // Both score within the table's f16 rounding of each other.
    let score = |checkpoint: &Path| -> f64 {
        let mut args = with(&[
            "eval",
            "--config",
            "nerf_lego_ngp",
            "--data-dir",
            data_arg,
            "--limit",
            "2",
            "--json",
            "--checkpoint",
        ]);
        args.insert(9, checkpoint.display().to_string());
        let json: serde_json::Value = serde_json::from_str(&run(&args)).unwrap();
        json["mean_psnr"].as_f64().unwrap()
    };
    let (a, b) = (score(&ckpt), score(&model));
    assert!((a - b).abs() < 0.05, "full {a} dB, exported {b} dB");
    // The exported model renders the surround views.
    let images = dir.path().join("images");
    let from_model = ["--checkpoint", model.to_str().unwrap()];
    run(&with(&render_args("nerf_lego_ngp", &images, &from_model)));
    assert!(images.join("render_nerf.gif").is_file());
}
