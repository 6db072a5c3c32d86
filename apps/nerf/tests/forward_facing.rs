//! A forward-facing capture through the binary: an LLFF capture (`poses_bounds.npy`) of
//! three spheres photographed by a 5×4 grid of parallel cameras, as LLFF's scenes are taken,
//! trains a few seconds with `nerf_scene`; its checkpoint stores a spiral in front of the
//! cameras, which `nerf render` and `nerf view` use, and the spiral's views see the scene where
//! the orbit's views (the same checkpoint with the spiral removed, as one written before
//! spirals were stored) mostly look past it. The photos and the expected pictures are
//! ray-cast here by hand, independently of the renderer under test.

mod common;

use std::path::Path;

use glam::DVec3;
use nerf::core::camera::Camera;
use nerf::core::camera::PerspectiveCamera;
use nerf::io::checkpoint::{self, read_metadata};
use nerf::io::dataset::SceneTransform;

/// Photo size and NDC focal length (75° across) of every camera.
const PHOTO: (u32, u32) = (48, 36);
const NDC_FOCAL: f64 = 1.3;

/// A sphere of the scene: centre, radius, colour.
struct Sphere {
    centre: DVec3,
    radius: f64,
    colour: [f64; 3],
}

/// The scene in the capture's own frame (+y up; the cameras look along −z): three spheres
/// 1.5 to 3.3 in front of the cameras' plane, on black.
fn scene() -> Vec<Sphere> {
    vec![
        Sphere {
            centre: DVec3::new(-0.5, 0.15, -2.0),
            radius: 0.45,
            colour: [0.9, 0.3, 0.2],
        },
        Sphere {
            centre: DVec3::new(0.55, -0.2, -2.5),
            radius: 0.5,
            colour: [0.2, 0.8, 0.3],
        },
        Sphere {
            centre: DVec3::new(0.1, 0.45, -2.9),
            radius: 0.35,
            colour: [0.3, 0.4, 0.95],
        },
    ]
}

/// The colour the ray `origin + t · direction` (unit direction) sees: the nearest sphere's,
/// lit from above and the front (Lambertian, with some ambient light); `None` on a miss.
fn trace(spheres: &[Sphere], origin: DVec3, direction: DVec3) -> Option<[f64; 3]> {
    let light = DVec3::new(0.3, 0.6, 0.7).normalize();
    spheres
        .iter()
        .filter_map(|s| {
            let to_centre = s.centre - origin;
            let along = to_centre.dot(direction);
            let miss2 = to_centre.length_squared() - along * along;
            let half_chord2 = s.radius * s.radius - miss2;
            let t = along - half_chord2.max(0.0).sqrt();
            (half_chord2 >= 0.0 && t > 0.0).then_some((t, s))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(t, s)| {
            let normal = (origin + t * direction - s.centre) / s.radius;
            let shade = 0.3 + 0.7 * normal.dot(light).max(0.0);
            s.colour.map(|c| c * shade)
        })
}

/// The camera centres: a 5×4 grid on the plane z = 0, 2.4 across and 1.2 high.
fn camera_centres() -> Vec<DVec3> {
    (0..20)
        .map(|i| {
            DVec3::new(
                -1.2 + 0.6 * (i % 5) as f64,
                -0.6 + 0.4 * (i / 5) as f64,
                0.0,
            )
        })
        .collect()
}

/// The LLFF capture in `dir`: `images/frame_NN.png` ray-cast from each camera (looking along
/// −z, +y up, COLMAP's pixel centres at `i + 0.5`), and `poses_bounds.npy` with each
/// camera's pose and the nearest and farthest sphere depth as its bounds.
fn write_capture(dir: &Path) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let spheres = scene();
    let (w, h) = PHOTO;
    let focal_px = NDC_FOCAL * w as f64 / 2.0;
    let mut rows = Vec::new();
    for (i, eye) in camera_centres().into_iter().enumerate() {
        let photo = image::RgbImage::from_fn(w, h, |u, v| {
            let x = (u as f64 + 0.5 - w as f64 / 2.0) / focal_px;
            let y = -(v as f64 + 0.5 - h as f64 / 2.0) / focal_px;
            let colour = trace(&spheres, eye, DVec3::new(x, y, -1.0).normalize());
            image::Rgb(
                colour
                    .unwrap_or([0.0; 3])
                    .map(|c| (c * 255.0).round() as u8),
            )
        });
        photo
            .save(dir.join("images").join(format!("frame_{i:02}.png")))
            .unwrap();
        // Rows of the camera → world matrix in LLFF's columns (down, right, back, centre,
        // [h, w, focal]): the camera's right is +x, up +y, back +z.
        let hwf = [h as f64, w as f64, focal_px];
        for (r, extra) in hwf.iter().enumerate() {
            let axis = |k: usize| f64::from(u8::from(r == k));
            rows.extend([-axis(1), axis(0), axis(2), eye[r], *extra]);
        }
        let depths = spheres.iter().map(|s| (eye.z - s.centre.z, s.radius));
        let near = depths
            .clone()
            .map(|(d, r)| d - r)
            .fold(f64::INFINITY, f64::min);
        let far = depths.map(|(d, r)| d + r).fold(0.0, f64::max);
        rows.extend([near, far]);
    }
    std::fs::write(
        dir.join("poses_bounds.npy"),
        common::lego_capture::npy_rows(&rows),
    )
    .unwrap();
}

/// Per view, the fraction of the pixels of a `size` picture that see a sphere, the spheres
/// moved into the normalised frame by `transform`.
fn true_coverage(
    cameras: &[PerspectiveCamera],
    transform: &SceneTransform,
    size: (usize, usize),
) -> Vec<f64> {
    let spheres: Vec<Sphere> = scene()
        .into_iter()
        .map(|s| Sphere {
            centre: transform.apply_point(s.centre),
            radius: s.radius * transform.scale,
            colour: s.colour,
        })
        .collect();
    cameras
        .iter()
        .map(|cam| {
            let hits = (0..size.1)
                .flat_map(|row| (0..size.0).map(move |col| (col, row)))
                .filter(|&(col, row)| {
                    let (o, d) = Camera::from(*cam).pixel_ray(col, row, size);
                    trace(&spheres, o, d).is_some()
                })
                .count();
            hits as f64 / (size.0 * size.1) as f64
        })
        .collect()
}

/// Per `color_NNN.npy` in `dir`, the fraction of its pixels brighter than the black
/// background (any channel above 0.1).
fn rendered_coverage(dir: &Path) -> Vec<f64> {
    common::sorted_names(dir)
        .into_iter()
        .filter(|n| n.starts_with("color_") && n.ends_with(".npy"))
        .map(|name| {
            let (shape, values) = common::read_npy(&dir.join(name));
            assert_eq!(shape[2], 3);
            let lit = values
                .chunks_exact(3)
                .filter(|rgb| rgb.iter().any(|c| *c > 0.1))
                .count();
            lit as f64 / (values.len() / 3) as f64
        })
        .collect()
}

fn vector(value: &serde_json::Value) -> DVec3 {
    let v: Vec<f64> = value
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    DVec3::new(v[0], v[1], v[2])
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

#[test]
fn a_forward_facing_capture_renders_and_views_from_a_spiral_that_sees_the_scene() {
    let root = tempfile::tempdir().unwrap();
    let capture = root.path().join("capture");
    write_capture(&capture);
    let ckpt = root.path().join("ff.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    const VIEWS: usize = 8;
    let views_arg = format!("cameras.n_poses={VIEWS}");
    // The spheres lie 1.1 to 2.5 ahead of the rig's centre in the normalised frame (the
    // farthest camera at 1): a box of ±3 holds them, and 7 reaches its far corner.
    let overrides = [
        "data.image_size=[48,36]",
        "training.eval_views=0",
        "sampler.n_pts_per_ray=64",
        "sampler.max_depth=7",
        "implicit_function.appearance_dim=0",
        "implicit_function.aabb=[[-3,-3,-3],[3,3,3]]",
        "renderer.occupancy_grid.aabb=[-3,-3,-3,3,3,3]",
        &views_arg,
        &ckpt_arg,
    ];
    let dir_arg = capture.to_str().unwrap();
    let with = |head: &[&str], extra: &[&str]| -> Vec<String> {
        head.iter()
            .chain(&["--config", "nerf_scene_bounded"])
            .chain(&overrides)
            .chain(extra)
            .map(|s| s.to_string())
            .collect()
    };
    let run = |args: Vec<String>| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        common::nerf_ok(&args)
    };
    let log = common::stderr(&run(with(
        &["train", "--epochs", "20"],
        &["--data-dir", dir_arg],
    )));
    assert!(log.contains("LLFF") && log.contains("normalised"), "{log}");

    // The checkpoint stores a spiral (the capture is forward-facing) beside the orbit.
    let meta = read_metadata(&ckpt).unwrap();
    let spiral = checkpoint::CAPTURE_SPIRAL
        .read(&meta, &ckpt)
        .unwrap()
        .expect("a spiral");
    let orbit = checkpoint::CAPTURE_ORBIT
        .read(&meta, &ckpt)
        .unwrap()
        .expect("an orbit");
    let transform = checkpoint::SCENE_TRANSFORM
        .read(&meta, &ckpt)
        .unwrap()
        .unwrap();
    // The mean camera looks along the capture's −z, and the focus lies among the spheres.
    let forward = transform.rotation * DVec3::NEG_Z;
    assert!(spiral.forward.dot(forward) > 1.0 - 1e-9, "{spiral:?}");
    let focus_depth = spiral.focus_distance / transform.scale;
    assert!((1.5..=3.3).contains(&focus_depth), "{focus_depth}");

    // render: the spiral's views, named on stderr.
    let spiral_dir = root.path().join("spiral");
    let out = spiral_dir.to_str().unwrap();
    let log = common::stderr(&run(with(&["render", "--raw"], &["--out-dir", out])));
    assert!(log.contains(&format!("{VIEWS} views on a spiral")), "{log}");
    assert!(spiral_dir.join("render_nerf.gif").is_file());
    let spiral_lit = rendered_coverage(&spiral_dir);

    // The same model without its spiral (a checkpoint written before spirals were stored)
    // renders the orbit, as before.
    let (tensors, info) = checkpoint::load(&ckpt, &candle_core::Device::Cpu).unwrap();
    let mut tensors: Vec<(String, candle_core::Tensor)> = tensors.into_iter().collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let old = root.path().join("orbit.safetensors");
    let old_info = checkpoint::CheckpointInfo {
        capture_spiral: None,
        ..info
    };
    checkpoint::save(&old, &tensors, old_info).unwrap();
    let old_arg = format!("training.checkpoint_path={}", old.display());
    let orbit_dir = root.path().join("orbit");
    let out = orbit_dir.to_str().unwrap();
    let log = common::stderr(&run(with(
        &["render", "--raw"],
        &["--out-dir", out, &old_arg],
    )));
    assert!(
        log.contains(&format!("{VIEWS} views on the capture's orbit")),
        "{log}"
    );
    let orbit_lit = rendered_coverage(&orbit_dir);

    // What each path's views truly see (ray-cast here), and what the model renders.
    let size = (48, 36);
    let spiral_true = true_coverage(&spiral.cameras(VIEWS), &transform, size);
    let orbit_true = true_coverage(&orbit.cameras(VIEWS), &transform, size);
    eprintln!(
        "forward-facing: spheres cover {:.3} (min {:.3}) of the spiral's views and {:.3} \
         (min {:.3}) of the orbit's; rendered non-black {:.3} (min {:.3}) and {:.3} (min {:.3})",
        mean(&spiral_true),
        spiral_true.iter().copied().fold(1.0, f64::min),
        mean(&orbit_true),
        orbit_true.iter().copied().fold(1.0, f64::min),
        mean(&spiral_lit),
        spiral_lit.iter().copied().fold(1.0, f64::min),
        mean(&orbit_lit),
        orbit_lit.iter().copied().fold(1.0, f64::min),
    );
    assert_eq!((spiral_lit.len(), orbit_lit.len()), (VIEWS, VIEWS));
    // Every spiral view sees the spheres, and renders them.
    for (i, (t, r)) in spiral_true.iter().zip(&spiral_lit).enumerate() {
        assert!(*t > 0.1, "spiral view {i}: the spheres cover {t}");
        assert!(*r > 0.5 * t, "spiral view {i}: {r} rendered of {t} true");
    }
    // The orbit looks past them from half its views or more.
    let blind = orbit_true.iter().filter(|t| **t < 0.02).count();
    assert!(2 * blind >= VIEWS, "{orbit_true:?}");
    assert!(mean(&spiral_true) > 2.0 * mean(&orbit_true));

    // view: starts from the first spiral view, looking at the focus with the spiral's up.
    let mut args = vec!["--config", "nerf_scene_bounded"];
    args.extend(overrides);
    let info = common::view_info(&args);
    let first = spiral.cameras(VIEWS)[0].center();
    assert!((vector(&info["eye"]) - first).length() < 1e-9, "{info}");
    assert!(
        (vector(&info["at"]) - spiral.focus()).length() < 1e-9,
        "{info}"
    );
    assert!((vector(&info["up"]) - spiral.up).length() < 1e-9, "{info}");
    assert_eq!(info["focal"].as_f64().unwrap(), spiral.focal[0]);

    // --camera-path still overrides the stored path.
    let path = root.path().join("path.json");
    let json = serde_json::json!({
        "camera_type": "perspective", "render_width": 16, "render_height": 12, "fps": 10,
        "seconds": 0.1,
        "camera_path": [{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], "fov": 60}],
    });
    std::fs::write(&path, json.to_string()).unwrap();
    let path_dir = root.path().join("path");
    let out = path_dir.to_str().unwrap();
    let log = common::stderr(&run(with(
        &["render"],
        &["--out-dir", out, "--camera-path", path.to_str().unwrap()],
    )));
    assert!(!log.contains("spiral"), "{log}");
    assert!(path_dir.join("frame_0000.png").is_file());
}
