//! Captures in the formats other NeRF tools read (COLMAP text and binary, nerfstudio
//! `transforms.json`, LLFF `poses_bounds.npy`), made here from the first 16 lego training
//! views, each read back through `--data-dir` detection. The cameras are checked against
//! pytorch3d's projection of the lego frames (written out by hand below, independent of the
//! loaders): a world point projected by the lego camera, in COLMAP's pixel convention, must lie
//! on the loaded camera's ray through that pixel, in the normalised frame.

mod common;

use common::lego_capture::*;

use std::path::Path;

use glam::DVec3;
use nerf::io::checkpoint;
use nerf::io::dataset::colmap_scene::COLMAP;
use nerf::io::dataset::llff::LLFF;
use nerf::io::dataset::nerfstudio::NERFSTUDIO;
use nerf::io::dataset::{read_capture_split, Dataset, SceneFormat, Split};

/// Reads the capture in `dir` as `format` and checks every split's cameras against the lego
/// views (see the module documentation) and the every-8th holdout.
fn check_capture(lego: &Lego, dir: &Path, format: SceneFormat) {
    assert_eq!(SceneFormat::detect(dir), format);
    let points = [
        DVec3::new(0.1, -0.2, 0.3),
        DVec3::new(-0.5, 0.4, -0.1),
        DVec3::ZERO,
    ];
    let mut seen = 0;
    for (split, expected) in [(Split::Train, 14), (Split::Test, 2)] {
        let read = read_capture_split(dir, format, split).unwrap();
        assert_eq!(read.frames.len(), expected, "{split}");
        assert_eq!(read.total_frames, FRAMES);
        for frame in &read.frames {
            let name = frame.file_path.file_stem().unwrap().to_string_lossy();
            let index: usize = name.trim_start_matches("frame_").parse().unwrap();
            // Sorted names frame_00..frame_15: the held-out ones are 0 and 8.
            assert_eq!(index.is_multiple_of(8), split == Split::Test, "{name}");
            let view = &lego.views[index];
            let nerf::core::camera::Camera::Colmap(camera) = &frame.camera else {
                panic!("a capture's camera is COLMAP's");
            };
            for p in points {
                let (u, v) = lego_pixel(view, lego.focal_px(), lego.size, p);
                let (o, d) = camera.ray_through_pixel(u, v);
                let q = read.transform.apply_point(p) - o;
                let miss = (q - d * q.dot(d)).length();
                assert!(miss < 1e-6, "{format:?} {name}: {miss}");
            }
            assert!(frame.camera.validate().is_ok());
            seen += 1;
        }
        // The normalised cameras stand at most 1 from the origin.
        let farthest = read
            .frames
            .iter()
            .map(|f| f.camera.center().length())
            .fold(0.0, f64::max);
        assert!(farthest <= 1.0 + 1e-9, "{farthest}");
    }
    assert_eq!(seen, FRAMES);
}

#[test]
fn colmap_text_and_binary_nerfstudio_and_llff_captures_give_the_lego_cameras() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let text = scratch.colmap_text("colmap_text");
    check_capture(lego, &text, COLMAP);
    // The same model written as binary, beside a second, smaller model: the larger is chosen.
    let binary = scratch.path("colmap_binary");
    let mut model = write_colmap_binary(lego, &text, &binary);
    model.images.truncate(3);
    nerf::io::colmap::write_binary(&binary.join("sparse").join("1"), &model).unwrap();
    check_capture(lego, &binary, COLMAP);
    let ns = scratch.path("nerfstudio");
    write_nerfstudio(lego, &ns);
    check_capture(lego, &ns, NERFSTUDIO);
    let llff = scratch.path("llff");
    write_llff(lego, &llff);
    check_capture(lego, &llff, LLFF);
}

#[test]
fn an_llff_file_written_for_larger_photos_is_scaled_to_the_photos_on_disk() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let dir = scratch.path("llff_full_size");
    // poses_bounds.npy says 4× the photos' size, as LLFF keeps it beside downscaled photos.
    write_llff_for_size(lego, &dir, 4.0);
    // The cameras are the photos' own: the same rays as lego's views.
    check_capture(lego, &dir, LLFF);
    let data: nerf::config::DataConfig =
        serde_yaml_ng::from_str("downscale: 2").expect("a data section");
    let size = data
        .dataset_image_size(&dir, nerf::config::SizeUse::Scoring)
        .unwrap();
    let half = (lego.size.0 as usize / 2, lego.size.1 as usize / 2);
    assert_eq!(size, half);
    let loaded = Dataset::load(&dir, Split::Test, size.0, size.1, false).unwrap();
    assert_eq!((loaded.width, loaded.height), half);
    assert_eq!(loaded.capture.as_ref().unwrap().photo_size, Some(lego.size));
    for frame in &loaded.frames {
        let nerf::core::camera::Camera::Colmap(camera) = &frame.camera else {
            panic!("a capture's camera is COLMAP's");
        };
        assert_eq!(camera.size, (lego.size.0 as usize, lego.size.1 as usize));
        // The focal length of the photos; at the loaded half size, half of it.
        assert!(
            (camera.focal[0] - lego.focal_px()).abs() < 1e-9,
            "{:?}",
            camera.focal
        );
        let at_size = camera.focal[0] * size.0 as f64 / camera.size.0 as f64;
        assert!((at_size - lego.focal_px() / 2.0).abs() < 1e-9);
    }
    // A camera file of another aspect than its photos is refused, naming both sizes.
    let wrong = scratch.path("llff_other_aspect");
    write_llff_for_size(lego, &wrong, 1.0);
    let npy = wrong.join("poses_bounds.npy");
    let mut bytes = std::fs::read(&npy).unwrap();
    let header = bytes.len() - FRAMES * 17 * 8;
    for row in 0..FRAMES {
        // The height, [0][4], doubled.
        let at = header + (row * 17 + 4) * 8;
        let h = f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
        bytes[at..at + 8].copy_from_slice(&(2.0 * h).to_le_bytes());
    }
    std::fs::write(&npy, bytes).unwrap();
    let err = read_capture_split(&wrong, LLFF, Split::Train)
        .unwrap_err()
        .to_string();
    let (w, h) = lego.size;
    let camera = format!("the camera is {w}x{} but its photo is {w}x{h}", 2 * h);
    assert!(err.contains(&camera) && !err.contains('\n'), "{err}");
}

#[test]
fn a_capture_whose_cameras_share_no_view_is_refused_in_one_line() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    // The lego photos on a ring of cameras each looking straight out, up +z (OpenGL columns:
    // right, up, back, centre).
    let views = lego
        .views
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let a = i as f64 * std::f64::consts::TAU / FRAMES as f64;
            let (c, s) = (a.cos(), a.sin());
            View {
                image: v.image.clone(),
                c2w: [
                    [s, 0.0, -c, 4.0 * c],
                    [-c, 0.0, -s, 4.0 * s],
                    [0.0, 1.0, 0.0, 0.0],
                    [0.0, 0.0, 0.0, 1.0],
                ],
            }
        })
        .collect();
    let outward = Lego {
        views,
        fov: lego.fov,
        size: lego.size,
    };
    let dir = scratch.path("outward_ring");
    write_colmap_text(&outward, &dir);
    let scene = scratch.tiny_scene("nerf_scene_bounded", 1);
    let err = error_line(&common::nerf(&scene.args("train", &dir, &[])));
    assert!(
        err.contains(&dir.display().to_string())
            && err.contains("no two of its 14 cameras see a common part of the scene"),
        "{err}"
    );
    assert!(!scene.checkpoint.exists());
}

#[test]
fn a_capture_loads_as_a_dataset_and_trains_and_evaluates_with_nerf_scene() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let capture = scratch.colmap_text("capture");
    let data = Dataset::load(&capture, Split::Test, 20, 20, false).unwrap();
    assert_eq!(data.frames.len(), 2);
    assert!(data
        .images
        .iter()
        .all(|im| im.width == 20 && im.height == 20));
    let scene = scratch.tiny_scene("nerf_scene_bounded", 1);
    let o = scene.run_ok("train", &capture, &[]);
    assert!(scene.checkpoint.is_file());
    let log = common::stderr(&o);
    assert!(
        log.contains("COLMAP capture") && log.contains("normalised"),
        "{log}"
    );
    let mut args = scene.args("eval", &capture, &["--split", "test"]);
    let o = common::nerf_ok(&args);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("PSNR"), "{out}");
    // The protocol in one line: the held-out frames, the appearance, the targets (at the
    // tiny scene's data.image_size, 24×24, not a whole fraction of the photos).
    let protocol = "protocol: 2 held-out frames (every 8th of the sorted photo names), mean \
         appearance vector of the training photos, targets resized by the triangle filter (not \
         a whole factor of the photos) to 24×24";
    let log = common::stderr(&o);
    assert!(log.contains(protocol), "{log}");
    assert!(
        log.contains("cameras from the COLMAP model sparse/0")
            && log.contains("(held out: every 8th of the sorted photo names)"),
        "{log}"
    );
    // At the photos' own size over data.downscale, written under their own names.
    let saved = scratch.path("saved");
    let saved_arg = saved.to_str().unwrap();
    args.extend(["data.downscale=16", "--save-images", saved_arg]);
    let o = common::nerf_ok(&args);
    let log = common::stderr(&o);
    let side = lego.size.0 / 16;
    let small = format!("targets box-downscaled 1/16 to {side}×{side}");
    assert!(log.contains(&small), "{log}");
    let side = (lego.size.0 as f64 / 16.0).round() as u32;
    for name in ["frame_00.png", "frame_08.png"] {
        assert_eq!(
            image::image_dimensions(saved.join(name)).unwrap(),
            (side, side)
        );
    }
    assert_eq!(common::sorted_names(&saved).len(), 2);
    args.push("data.downscale=0.5");
    let err = common::one_line_error(&common::nerf(&args));
    assert!(err.contains("data.downscale"), "{err}");
}

#[test]
fn the_checkpoint_keeps_the_scene_normalisation_it_was_trained_in() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let full = scratch.colmap_text("full");
    // The first 9 photos only: the same held-out frames (frame_00 and frame_08), but the
    // cameras give another normalisation.
    let subset = scratch.path("subset");
    write_colmap_text(&lego.first(9), &subset);
    let trained_in = read_capture_split(&full, COLMAP, Split::Test)
        .unwrap()
        .transform;
    let recomputed = read_capture_split(&subset, COLMAP, Split::Test)
        .unwrap()
        .transform;
    assert!(!trained_in.agrees_with(&recomputed, 1e-3));

    let scene = scratch.tiny_scene("nerf_scene_bounded", 2);
    scene.run_ok("train", &full, &[]);
    let (ckpt, overrides) = (&scene.checkpoint, scene.overrides());
    // Stored exactly.
    let meta = checkpoint::read_metadata(ckpt).unwrap();
    assert_eq!(
        checkpoint::SCENE_TRANSFORM.read(&meta, ckpt).unwrap(),
        Some(trained_in)
    );

    // The library: the subset's cameras in the stored frame are the full capture's.
    let load = |dir: &Path, stored| {
        Dataset::load_first_with(dir, Split::Test, (24, 24), false, None, stored).unwrap()
    };
    let reference = load(&full, None);
    let moved = load(&subset, Some(trained_in));
    let cameras = |d: &Dataset| {
        d.frames
            .iter()
            .map(|f| f.camera.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(cameras(&moved), cameras(&reference));
    assert_ne!(cameras(&load(&subset, None)), cameras(&reference));
    let n = moved.normalisation.unwrap();
    assert!(n.applied == trained_in && !n.is_from_cameras());

    // The command: eval of the subset renders what eval of the full capture renders, and
    // says which normalisation it used.
    let eval = |dir: &Path, checkpoint: &Path, saved: &Path| {
        let mut args = vec!["eval", "--config", "nerf_scene_bounded", "--split", "test"];
        args.extend(["--data-dir", dir.to_str().unwrap()]);
        args.extend(["--checkpoint", checkpoint.to_str().unwrap()]);
        args.extend(["--save-images", saved.to_str().unwrap()]);
        args.extend(overrides);
        common::stderr(&common::nerf_ok(&args))
    };
    let (on_full, on_subset) = (scratch.path("a"), scratch.path("b"));
    let log = eval(&full, ckpt, &on_full);
    assert!(!log.contains("not the one these cameras give"), "{log}");
    let log = eval(&subset, ckpt, &on_subset);
    assert!(
        log.contains("using the scene normalisation stored in"),
        "{log}"
    );
    assert_eq!(files_of(&on_full).len(), 2);
    assert_eq!(files_of(&on_subset), files_of(&on_full));
    // export reads the views in the stored frame too.
    let export = |dir: &Path, out: &Path| {
        let mut args = vec![
            "export",
            "depth",
            "--config",
            "nerf_scene_bounded",
            "--split",
            "test",
        ];
        args.extend(["--data-dir", dir.to_str().unwrap()]);
        args.extend(["--checkpoint", ckpt.to_str().unwrap()]);
        args.extend(["--out", out.to_str().unwrap()]);
        args.extend(overrides);
        common::nerf_ok(&args);
        files_of(out)
    };
    let depth = export(&full, &scratch.path("depth_a"));
    assert_eq!(depth.len(), 4);
    assert_eq!(export(&subset, &scratch.path("depth_b")), depth);
    // Without the stored transform (a checkpoint from before it was stored), the subset's
    // recomputed frame renders other images: the check above can tell them apart.
    let old = scratch.path("old.safetensors");
    resave_checkpoint(ckpt, &old, |info| info.scene_transform = None);
    let recomputed_images = scratch.path("c");
    let log = eval(&subset, &old, &recomputed_images);
    assert!(log.contains("stores no scene normalisation"), "{log}");
    assert_ne!(files_of(&recomputed_images), files_of(&on_full));
    // A resumed run on the subset keeps training in the stored frame, and keeps storing it;
    // and over the object's stored cube, though the subset's silhouettes carve another hull.
    let cube = checkpoint::OBJECT_BOX.read(&checkpoint::read_metadata(ckpt).unwrap(), ckpt);
    let cube = cube
        .unwrap()
        .expect("lego's views have alpha: an object fit");
    let args = scene.args("train", &subset, &["training.num_epochs=3"]);
    let log = common::stderr(&common::nerf_ok(&args));
    assert!(
        log.contains("resuming from") && log.contains("using the scene normalisation stored in"),
        "{log}"
    );
    assert!(
        log.contains("keeping the object's depths and cube stored in"),
        "{log}"
    );
    let meta = checkpoint::read_metadata(ckpt).unwrap();
    assert_eq!(
        checkpoint::OBJECT_BOX.read(&meta, ckpt).unwrap(),
        Some(cube)
    );
    assert_eq!(meta["epoch"], "3");
    assert_eq!(
        checkpoint::SCENE_TRANSFORM.read(&meta, ckpt).unwrap(),
        Some(trained_in)
    );
}

#[test]
fn an_instant_ngp_capture_gives_the_nerfstudio_cameras_and_trains() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let ns = scratch.path("nerfstudio");
    write_nerfstudio(lego, &ns);
    // In colmap2nerf's own gauge (centres scaled and moved, scale and offset written), and in
    // the nerfstudio file's.
    let moved = scratch.path("ngp_moved");
    write_colmap2nerf(lego, &moved, Some((2.5, [0.5, -1.0, 3.0])));
    let same = scratch.path("ngp");
    write_colmap2nerf(lego, &same, None);
    // The lego projection check holds in the lego world frame, which `same` keeps.
    check_capture(lego, &same, NERFSTUDIO);
    for dir in [&moved, &same] {
        for split in [Split::Train, Split::Test] {
            let a = read_capture_split(&ns, NERFSTUDIO, split).unwrap();
            let b = read_capture_split(dir, NERFSTUDIO, split).unwrap();
            assert_eq!(a.frames.len(), b.frames.len());
            for (a, b) in a.frames.iter().zip(&b.frames) {
                assert_eq!(a.file_path.file_name(), b.file_path.file_name());
                let (nerf::core::camera::Camera::Colmap(a), nerf::core::camera::Camera::Colmap(b)) =
                    (&a.camera, &b.camera)
                else {
                    panic!("a capture's camera is COLMAP's");
                };
                assert_eq!(a.size, b.size);
                assert_eq!(a.distortion, b.distortion);
                let close = |x: &[f64], y: &[f64], tol: f64| {
                    x.iter().zip(y).all(|(x, y)| (x - y).abs() <= tol)
                };
                assert!(close(&a.focal, &b.focal, 1e-9), "{a:?} {b:?}");
                assert!(close(&a.principal_point, &b.principal_point, 0.0));
                let rotation = (a.pose.rotation - b.pose.rotation).to_cols_array();
                assert!(rotation.iter().all(|v| v.abs() < 1e-9), "{a:?} {b:?}");
                let moved_by = (a.pose.translation - b.pose.translation).length();
                assert!(moved_by < 1e-9, "{}: {moved_by}", dir.display());
            }
        }
    }

    // The command: a model trained on the colmap2nerf file renders its held-out views as it
    // renders the nerfstudio file's (the same cameras, to float64 rounding).
    let scene = scratch.tiny_scene("nerf_scene", 1);
    let run = |command: &str, dir: &Path, extra: &[&str]| {
        common::stderr(&scene.run_ok(command, dir, extra))
    };
    let log = run("train", &same, &[]);
    assert!(log.contains("instant-ngp (transforms.json)"), "{log}");
    let (a, b) = (scratch.path("a"), scratch.path("b"));
    for (dir, saved) in [(&same, &a), (&ns, &b)] {
        let saved = saved.to_str().unwrap();
        let log = run("eval", dir, &["--split", "test", "--save-images", saved]);
        assert!(!log.contains("not the one these cameras give"), "{log}");
    }
    let (a, b) = (files_of(&a), files_of(&b));
    assert_eq!(a.len(), 2);
    for ((name_a, png_a), (name_b, png_b)) in a.iter().zip(&b) {
        assert_eq!(name_a, name_b);
        let decode = |png: &[u8]| image::load_from_memory(png).unwrap().to_rgb8();
        let (x, y) = (decode(png_a), decode(png_b));
        let worst = common::max_channel_difference(&x, &y);
        assert!(worst <= 1, "{name_a}: {worst}");
    }
}
