//! Captures in the formats other NeRF tools read (COLMAP text and binary, nerfstudio
//! `transforms.json`, LLFF `poses_bounds.npy`), made here from the first 16 lego training
//! views, each read back through `--data-dir` detection. The cameras are checked against
//! pytorch3d's projection of the lego frames (written out by hand below, independent of the
//! loaders): a world point projected by the lego camera, in COLMAP's pixel convention, must lie
//! on the loaded camera's ray through that pixel, in the normalised frame.

mod common;

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use nerf::core::camera_model::CameraModel;
use nerf::io::checkpoint;
use nerf::io::dataset::{read_capture_split, Dataset, SceneFormat, Split};

const FRAMES: usize = 16;

/// One lego training view: image, camera → world (Blender/OpenGL axes), image size.
struct View {
    image: PathBuf,
    c2w: [[f64; 4]; 4],
}

struct Lego {
    views: Vec<View>,
    fov: f64,
    size: (u32, u32),
}

fn lego(test: &str) -> Option<Lego> {
    let dir = common::lego_dir(test)?;
    let text = std::fs::read_to_string(dir.join("transforms_train.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let fov = json["camera_angle_x"].as_f64().unwrap();
    let views: Vec<View> = json["frames"]
        .as_array()
        .unwrap()
        .iter()
        .take(FRAMES)
        .map(|f| {
            let m = f["transform_matrix"].as_array().unwrap();
            let c2w = std::array::from_fn(|i| {
                std::array::from_fn(|j| m[i].as_array().unwrap()[j].as_f64().unwrap())
            });
            let name = f["file_path"].as_str().unwrap().trim_start_matches("./");
            View {
                image: dir.join(format!("{name}.png")),
                c2w,
            }
        })
        .collect();
    let size = image::image_dimensions(&views[0].image).unwrap();
    Some(Lego { views, fov, size })
}

impl Lego {
    /// The first `n` views only.
    fn first(&self, n: usize) -> Lego {
        let views = self.views[..n]
            .iter()
            .map(|v| View {
                image: v.image.clone(),
                c2w: v.c2w,
            })
            .collect();
        Lego {
            views,
            fov: self.fov,
            size: self.size,
        }
    }

    /// Focal length in pixels: half the width over tan(fov / 2).
    fn focal_px(&self) -> f64 {
        0.5 * self.size.0 as f64 / (0.5 * self.fov).tan()
    }

    /// `images/frame_NN.png` copies of the views, in `dir`.
    fn copy_images(&self, dir: &Path) -> Vec<String> {
        std::fs::create_dir_all(dir.join("images")).unwrap();
        (0..self.views.len())
            .map(|i| {
                let name = format!("frame_{i:02}.png");
                std::fs::copy(&self.views[i].image, dir.join("images").join(&name)).unwrap();
                name
            })
            .collect()
    }
}

/// The pixel `(u, v)` (COLMAP's convention, pixel centres at i + 0.5) where the lego view sees
/// `point`, by pinhole projection in the view's OpenGL camera axes (+x right, +y up, looking
/// along −z).
fn lego_pixel(view: &View, focal: f64, size: (u32, u32), point: DVec3) -> (f64, f64) {
    let col = |j: usize| DVec3::new(view.c2w[0][j], view.c2w[1][j], view.c2w[2][j]);
    let q = point - col(3);
    let (x, y, z) = (q.dot(col(0)), q.dot(col(1)), q.dot(col(2)));
    let depth = -z;
    assert!(depth > 0.0);
    (
        size.0 as f64 / 2.0 + focal * x / depth,
        size.1 as f64 / 2.0 - focal * y / depth,
    )
}

/// OpenCV world → camera rotation and translation of a Blender camera → world matrix.
fn opencv_pose(c2w: &[[f64; 4]; 4]) -> (DMat3, DVec3) {
    let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
    let c2w_cv = DMat3::from_cols(col(0), -col(1), -col(2));
    let r = c2w_cv.transpose();
    (r, -(r * col(3)))
}

fn write_colmap_text(lego: &Lego, dir: &Path) {
    let names = lego.copy_images(dir);
    let sparse = dir.join("sparse").join("0");
    std::fs::create_dir_all(&sparse).unwrap();
    let (w, h) = lego.size;
    let f = lego.focal_px();
    std::fs::write(
        sparse.join("cameras.txt"),
        format!(
            "# one camera\n1 PINHOLE {w} {h} {f} {f} {} {}\n",
            w as f64 / 2.0,
            h as f64 / 2.0
        ),
    )
    .unwrap();
    let mut images = String::from("# images\n");
    for (i, (view, name)) in lego.views.iter().zip(&names).enumerate() {
        let (r, t) = opencv_pose(&view.c2w);
        let q = DQuat::from_mat3(&r);
        images += &format!(
            "{} {} {} {} {} {} {} {} 1 {name}\n\n",
            i + 1,
            q.w,
            q.x,
            q.y,
            q.z,
            t.x,
            t.y,
            t.z
        );
    }
    std::fs::write(sparse.join("images.txt"), images).unwrap();
    std::fs::write(sparse.join("points3D.txt"), "# none\n").unwrap();
}

fn write_nerfstudio(lego: &Lego, dir: &Path) {
    let names = lego.copy_images(dir);
    let (w, h) = lego.size;
    let frames: Vec<serde_json::Value> = lego
        .views
        .iter()
        .zip(&names)
        .map(|(v, name)| serde_json::json!({"file_path": format!("images/{name}"), "transform_matrix": v.c2w}))
        .collect();
    let json = serde_json::json!({
        "camera_model": "OPENCV", "fl_x": lego.focal_px(), "fl_y": lego.focal_px(),
        "cx": w as f64 / 2.0, "cy": h as f64 / 2.0, "w": w, "h": h, "frames": frames,
    });
    std::fs::write(dir.join("transforms.json"), json.to_string()).unwrap();
}

fn write_llff(lego: &Lego, dir: &Path) {
    lego.copy_images(dir);
    let (w, h) = lego.size;
    let mut values = Vec::new();
    for v in &lego.views {
        // Columns (down, right, back, centre, hwf) row by row; down = −up.
        let m = &v.c2w;
        let hwf = [h as f64, w as f64, lego.focal_px()];
        for (i, extra) in hwf.iter().enumerate() {
            values.extend([-m[i][1], m[i][0], m[i][2], m[i][3], *extra]);
        }
        values.extend([2.0, 6.0]);
    }
    std::fs::write(dir.join("poses_bounds.npy"), npy_rows(&values)).unwrap();
}

/// A float64 `.npy` file of shape `(N, 17)` holding `values` row by row.
fn npy_rows(values: &[f64]) -> Vec<u8> {
    let header = format!(
        "{{'descr': '<f8', 'fortran_order': False, 'shape': ({}, 17), }}",
        values.len() / 17
    );
    let pad = 64 - (10 + header.len() + 1) % 64;
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend(((header.len() + pad + 1) as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    bytes.extend(std::iter::repeat_n(b' ', pad));
    bytes.push(b'\n');
    for v in values {
        bytes.extend(v.to_le_bytes());
    }
    bytes
}

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
            let nerf::core::frame_camera::FrameCamera::Colmap(camera) = &frame.camera else {
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
    let Some(lego) =
        lego("colmap_text_and_binary_nerfstudio_and_llff_captures_give_the_lego_cameras")
    else {
        return;
    };
    let root = tempfile::tempdir().unwrap();
    let text = root.path().join("colmap_text");
    write_colmap_text(&lego, &text);
    check_capture(&lego, &text, SceneFormat::Colmap);
    // The same model written as binary, beside a second, smaller model: the larger is chosen.
    let binary = root.path().join("colmap_binary");
    lego.copy_images(&binary);
    let (_, mut model) = nerf::io::colmap::find_model(&text).unwrap();
    nerf::io::colmap::write_binary(&binary.join("sparse").join("0"), &model).unwrap();
    model.images.truncate(3);
    nerf::io::colmap::write_binary(&binary.join("sparse").join("1"), &model).unwrap();
    check_capture(&lego, &binary, SceneFormat::Colmap);
    let ns = root.path().join("nerfstudio");
    write_nerfstudio(&lego, &ns);
    check_capture(&lego, &ns, SceneFormat::Nerfstudio);
    let llff = root.path().join("llff");
    write_llff(&lego, &llff);
    check_capture(&lego, &llff, SceneFormat::Llff);
}

#[test]
fn a_capture_loads_as_a_dataset_and_trains_and_evaluates_with_nerf_scene() {
    let test = "a_capture_loads_as_a_dataset_and_trains_and_evaluates_with_nerf_scene";
    let Some(lego) = lego(test) else { return };
    let root = tempfile::tempdir().unwrap();
    let capture = root.path().join("capture");
    write_colmap_text(&lego, &capture);
    let data = Dataset::load(&capture, Split::Test, 20, 20, false).unwrap();
    assert_eq!(data.frames.len(), 2);
    assert!(data
        .images
        .iter()
        .all(|im| im.width == 20 && im.height == 20));
    let ckpt = root.path().join("scene.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    let overrides = [
        "data.image_size=[24,24]",
        "training.num_epochs=1",
        "training.eval_views=0",
        "sampler.n_pts_per_ray=32",
        &ckpt_arg,
    ];
    let dir_arg = capture.to_str().unwrap();
    let mut args = vec!["train", "--config", "nerf_scene", "--data-dir", dir_arg];
    args.extend(overrides);
    let o = common::nerf_ok(&args);
    assert!(ckpt.is_file());
    let log = common::stderr(&o);
    assert!(
        log.contains("COLMAP capture") && log.contains("normalised"),
        "{log}"
    );
    let mut args = vec![
        "eval",
        "--config",
        "nerf_scene",
        "--data-dir",
        dir_arg,
        "--split",
        "test",
    ];
    args.extend(overrides);
    let o = common::nerf_ok(&args);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("PSNR"), "{out}");
    // At the photos' own size over data.downscale, written under their own names.
    let saved = root.path().join("saved");
    let saved_arg = saved.to_str().unwrap();
    args.extend(["data.downscale=16", "--save-images", saved_arg]);
    common::nerf_ok(&args);
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

/// The one `error:` line of a run that failed with status 1 (a capture's loader logs what it
/// read on the lines before it), without a panic.
fn error_line(o: &std::process::Output) -> String {
    let log = common::stderr(o);
    assert_eq!(o.status.code(), Some(1), "{log}");
    assert!(!log.contains("panicked"), "{log}");
    let errors: Vec<&str> = log.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "{log}");
    errors[0].to_string()
}

/// The bytes of every file in `dir`, by name.
fn files_of(dir: &Path) -> Vec<(String, Vec<u8>)> {
    common::sorted_names(dir)
        .into_iter()
        .map(|n| {
            let bytes = std::fs::read(dir.join(&n)).unwrap();
            (n, bytes)
        })
        .collect()
}

#[test]
fn the_checkpoint_keeps_the_scene_normalisation_it_was_trained_in() {
    let test = "the_checkpoint_keeps_the_scene_normalisation_it_was_trained_in";
    let Some(lego) = lego(test) else { return };
    let root = tempfile::tempdir().unwrap();
    let full = root.path().join("full");
    write_colmap_text(&lego, &full);
    // The first 9 photos only: the same held-out frames (frame_00 and frame_08), but the
    // cameras give another normalisation.
    let subset = root.path().join("subset");
    write_colmap_text(&lego.first(9), &subset);
    let trained_in = read_capture_split(&full, SceneFormat::Colmap, Split::Test)
        .unwrap()
        .transform;
    let recomputed = read_capture_split(&subset, SceneFormat::Colmap, Split::Test)
        .unwrap()
        .transform;
    assert!(!trained_in.agrees_with(&recomputed, 1e-3));

    let ckpt = root.path().join("scene.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    let overrides = [
        "data.image_size=[24,24]",
        "training.num_epochs=2",
        "training.eval_views=0",
        "sampler.n_pts_per_ray=32",
        &ckpt_arg,
    ];
    let mut args = vec!["train", "--config", "nerf_scene", "--data-dir"];
    args.push(full.to_str().unwrap());
    args.extend(overrides);
    common::nerf_ok(&args);
    // Stored exactly.
    let meta = checkpoint::read_metadata(&ckpt).unwrap();
    assert_eq!(
        checkpoint::scene_transform_of(&meta, &ckpt).unwrap(),
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
        let mut args = vec!["eval", "--config", "nerf_scene", "--split", "test"];
        args.extend(["--data-dir", dir.to_str().unwrap()]);
        args.extend(["--checkpoint", checkpoint.to_str().unwrap()]);
        args.extend(["--save-images", saved.to_str().unwrap()]);
        args.extend(overrides);
        common::stderr(&common::nerf_ok(&args))
    };
    let (on_full, on_subset) = (root.path().join("a"), root.path().join("b"));
    let log = eval(&full, &ckpt, &on_full);
    assert!(!log.contains("not the one these cameras give"), "{log}");
    let log = eval(&subset, &ckpt, &on_subset);
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
            "nerf_scene",
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
    let depth = export(&full, &root.path().join("depth_a"));
    assert_eq!(depth.len(), 4);
    assert_eq!(export(&subset, &root.path().join("depth_b")), depth);
    // Without the stored transform (a checkpoint from before it was stored), the subset's
    // recomputed frame renders other images: the check above can tell them apart.
    let (tensors, mut info) = checkpoint::load(&ckpt, &candle_core::Device::Cpu).unwrap();
    info.scene_transform = None;
    let old = root.path().join("old.safetensors");
    let mut tensors: Vec<_> = tensors.into_iter().collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    checkpoint::save(&old, &tensors, info).unwrap();
    let recomputed_images = root.path().join("c");
    let log = eval(&subset, &old, &recomputed_images);
    assert!(log.contains("stores no scene normalisation"), "{log}");
    assert_ne!(files_of(&recomputed_images), files_of(&on_full));
    // A resumed run on the subset keeps training in the stored frame, and keeps storing it.
    let mut args = vec!["train", "--config", "nerf_scene", "--data-dir"];
    args.push(subset.to_str().unwrap());
    args.extend(overrides);
    args.push("training.num_epochs=3");
    let log = common::stderr(&common::nerf_ok(&args));
    assert!(
        log.contains("resuming from") && log.contains("using the scene normalisation stored in"),
        "{log}"
    );
    let meta = checkpoint::read_metadata(&ckpt).unwrap();
    assert_eq!(meta["epoch"], "3");
    assert_eq!(
        checkpoint::scene_transform_of(&meta, &ckpt).unwrap(),
        Some(trained_in)
    );
}

/// Masks for every frame of the capture in `dir` (the left `cut` columns ignored), written as
/// `masks/frame_NN.png` of `size`; `paint` also paints the ignored part of each photo magenta.
fn write_masks(dir: &Path, frames: usize, size: (u32, u32), cut: u32, paint: bool) {
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    for i in 0..frames {
        let name = format!("frame_{i:02}.png");
        let mask = image::GrayImage::from_fn(size.0, size.1, |x, _| {
            image::Luma([if x < cut { 0 } else { 255 }])
        });
        mask.save(dir.join("masks").join(&name)).unwrap();
        if paint {
            let photo = dir.join("images").join(&name);
            let mut rgba = image::open(&photo).unwrap().to_rgba8();
            for (x, _, p) in rgba.enumerate_pixels_mut() {
                if x < cut {
                    *p = image::Rgba([255, 0, 255, 255]);
                }
            }
            rgba.save(&photo).unwrap();
        }
    }
}

/// Adds `mask_path: masks/<photo name>` to every frame of `dir/transforms.json`.
fn add_mask_paths(dir: &Path) {
    let path = dir.join("transforms.json");
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for frame in json["frames"].as_array_mut().unwrap() {
        let name = frame["file_path"]
            .as_str()
            .unwrap()
            .replace("images/", "masks/");
        frame["mask_path"] = serde_json::json!(name);
    }
    std::fs::write(&path, json.to_string()).unwrap();
}

#[test]
fn masks_ignore_pixels_in_training_and_scoring_and_bad_ones_are_named() {
    let test = "masks_ignore_pixels_in_training_and_scoring_and_bad_ones_are_named";
    let Some(lego) = lego(test) else { return };
    let root = tempfile::tempdir().unwrap();
    let cut = lego.size.0 / 2;
    // nerfstudio: mask_path per frame.
    let ns = root.path().join("nerfstudio");
    write_nerfstudio(&lego, &ns);
    write_masks(&ns, FRAMES, lego.size, cut, false);
    add_mask_paths(&ns);
    // COLMAP: masks/ beside images/, and the ignored halves of the photos painted over.
    let painted = root.path().join("colmap");
    write_colmap_text(&lego, &painted);
    write_masks(&painted, FRAMES, lego.size, cut, true);
    for dir in [&ns, &painted] {
        let data = Dataset::load(dir, Split::Test, 20, 10, false).unwrap();
        assert_eq!(data.masks.len(), 2);
        let used = data.mask(0).unwrap().used();
        // 20 columns, the left 10 ignored, and the one next to them, whose colour the
        // resize mixes from both sides, may be too; the same on every row.
        let first = (0..20).position(|x| used[x]).unwrap();
        assert!((10..=11).contains(&first), "{used:?}");
        assert!((0..200).all(|p| used[p] == (p % 20 >= first)), "{used:?}");
    }

    let ckpt = root.path().join("scene.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    let overrides = [
        "data.image_size=[24,24]",
        "training.num_epochs=1",
        "training.eval_views=0",
        "sampler.n_pts_per_ray=32",
        &ckpt_arg,
    ];
    let run = |command: &str, dir: &Path| {
        let mut args = vec![command, "--config", "nerf_scene", "--data-dir"];
        args.push(dir.to_str().unwrap());
        args.extend(overrides);
        if command == "eval" {
            args.extend(["--split", "test"]);
        }
        common::nerf(&args)
    };
    assert!(run("train", &painted).status.success());
    // PSNR is over the used pixels: the painted halves change nothing.
    let psnr_of = |o: std::process::Output| {
        assert!(o.status.success(), "{}", common::stderr(&o));
        let out = String::from_utf8_lossy(&o.stdout).to_string();
        let at = out.find("PSNR mean ").unwrap() + "PSNR mean ".len();
        out[at..].split_whitespace().next().unwrap().to_string()
    };
    let plain = root.path().join("plain");
    write_colmap_text(&lego, &plain);
    write_masks(&plain, FRAMES, lego.size, cut, false);
    let on_painted = psnr_of(run("eval", &painted));
    assert_eq!(on_painted, psnr_of(run("eval", &plain)));
    // Without the masks the magenta halves are scored, and the PSNR falls.
    std::fs::remove_dir_all(painted.join("masks")).unwrap();
    let unmasked: f64 = psnr_of(run("eval", &painted)).parse().unwrap();
    assert!(
        unmasked < on_painted.parse::<f64>().unwrap() - 1.0,
        "{unmasked}"
    );

    // A mask of another size, and a missing one: one line naming the file; nothing written.
    let fresh = root.path().join("fresh.safetensors");
    let fresh_arg = format!("training.checkpoint_path={}", fresh.display());
    let bad_size = plain.join("masks").join("frame_03.png");
    image::GrayImage::new(7, 5).save(&bad_size).unwrap();
    let missing = plain.join("masks").join("frame_05.png");
    for (file, says) in [(&bad_size, "is 7x5"), (&missing, "")] {
        let mut args = vec!["train", "--config", "nerf_scene", "--data-dir"];
        args.push(plain.to_str().unwrap());
        args.extend([
            "data.image_size=[24,24]",
            "training.num_epochs=1",
            &fresh_arg,
        ]);
        if file == &missing {
            std::fs::copy(&missing, &bad_size).unwrap();
            std::fs::remove_file(&missing).unwrap();
        }
        let err = error_line(&common::nerf(&args));
        assert!(
            err.contains(&file.display().to_string()) && err.contains(says),
            "{err}"
        );
        assert!(!fresh.exists());
    }
}

#[test]
fn one_checkpoint_renders_the_same_images_from_the_text_and_binary_colmap_model() {
    let test = "one_checkpoint_renders_the_same_images_from_the_text_and_binary_colmap_model";
    let Some(lego) = lego(test) else { return };
    let root = tempfile::tempdir().unwrap();
    let text = root.path().join("text");
    write_colmap_text(&lego, &text);
    let binary = root.path().join("binary");
    lego.copy_images(&binary);
    let (_, model) = nerf::io::colmap::find_model(&text).unwrap();
    nerf::io::colmap::write_binary(&binary.join("sparse").join("0"), &model).unwrap();
    assert!(binary.join("sparse/0/images.bin").is_file());
    let ckpt = root.path().join("scene.safetensors");
    let ckpt_arg = format!("training.checkpoint_path={}", ckpt.display());
    let overrides = [
        "data.image_size=[24,24]",
        "training.num_epochs=1",
        "training.eval_views=0",
        "sampler.n_pts_per_ray=32",
        &ckpt_arg,
    ];
    let run = |command: &str, dir: &Path, extra: &[&str]| {
        let mut args = vec![command, "--config", "nerf_scene", "--data-dir"];
        args.push(dir.to_str().unwrap());
        args.extend(overrides);
        args.extend(extra);
        common::nerf_ok(&args)
    };
    run("train", &text, &[]);
    let (a, b) = (root.path().join("a"), root.path().join("b"));
    for (dir, saved) in [(&text, &a), (&binary, &b)] {
        let saved = saved.to_str().unwrap();
        run("eval", dir, &["--split", "test", "--save-images", saved]);
    }
    assert_eq!(files_of(&a).len(), 2);
    assert_eq!(files_of(&a), files_of(&b));
}

/// Replaces `from` by `to` in the text file `path` (once, which must match).
fn edit(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{}: no {from}", path.display());
    std::fs::write(path, text.replacen(from, to, 1)).unwrap();
}

#[test]
fn each_loaders_bad_input_is_one_line_naming_the_file_and_nothing_is_written() {
    let test = "each_loaders_bad_input_is_one_line_naming_the_file_and_nothing_is_written";
    let Some(lego) = lego(test) else { return };
    let lego = lego.first(4);
    let root = tempfile::tempdir().unwrap();
    // A way to break a capture, returning the file the error must name.
    type Breakage = fn(&Path) -> PathBuf;
    // What is broken, how, and what the error must also say.
    type Case<'a> = (&'a str, Breakage, &'a str);
    // A format's writer.
    type Writer = fn(&Lego, &Path);
    let missing_images: Breakage = |d| {
        std::fs::remove_dir_all(d.join("images")).unwrap();
        d.join("images")
    };
    fn absent_image(d: &Path) -> PathBuf {
        let photo = d.join("images").join("frame_02.png");
        std::fs::remove_file(&photo).unwrap();
        photo
    }
    let colmap: [Case; 5] = [
        ("missing images/", missing_images, ""),
        (
            "unknown camera model",
            |d| {
                let cameras = d.join("sparse").join("0").join("cameras.txt");
                // COLMAP's FOV model (fx fy cx cy omega), which no loader here supports.
                let text = std::fs::read_to_string(&cameras).unwrap();
                let line = text.lines().find(|l| l.contains("PINHOLE")).unwrap();
                let fov = format!("{} 0.1", line.replace("PINHOLE", "FOV"));
                std::fs::write(&cameras, text.replacen(line, &fov, 1)).unwrap();
                cameras
            },
            "FOV",
        ),
        ("image listed but absent", absent_image, ""),
        (
            "NaN pose",
            |d| {
                let images = d.join("sparse").join("0").join("images.txt");
                let text = std::fs::read_to_string(&images).unwrap();
                let line = text.lines().find(|l| l.starts_with("2 ")).unwrap();
                let mut fields: Vec<&str> = line.split(' ').collect();
                fields[5] = "nan";
                std::fs::write(&images, text.replacen(line, &fields.join(" "), 1)).unwrap();
                images
            },
            "",
        ),
        (
            "zero registered images",
            |d| {
                let images = d.join("sparse").join("0").join("images.txt");
                std::fs::write(&images, "# no images\n").unwrap();
                images
            },
            "",
        ),
    ];
    let nerfstudio: [Case; 5] = [
        ("missing images/", missing_images, ""),
        (
            "unknown camera model",
            |d| {
                let json = d.join("transforms.json");
                edit(&json, "\"OPENCV\"", "\"EQUIRECTANGULAR\"");
                json
            },
            "EQUIRECTANGULAR",
        ),
        ("image listed but absent", absent_image, ""),
        (
            "NaN pose",
            |d| {
                let json = d.join("transforms.json");
                let text = std::fs::read_to_string(&json).unwrap();
                let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
                // Python's json module writes a NaN as the bare token NaN, which JSON lacks.
                v["frames"][1]["transform_matrix"][0][3] = serde_json::json!("REPLACE");
                let text = v.to_string().replace("\"REPLACE\"", "NaN");
                std::fs::write(&json, text).unwrap();
                json
            },
            "transform_matrix",
        ),
        (
            "zero registered images",
            |d| {
                let json = d.join("transforms.json");
                let mut v: serde_json::Value =
                    serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
                v["frames"] = serde_json::json!([]);
                std::fs::write(&json, v.to_string()).unwrap();
                json
            },
            "no frames",
        ),
    ];
    let llff: [Case; 4] = [
        ("missing images/", missing_images, ""),
        (
            "image absent",
            |d| {
                absent_image(d);
                d.join("poses_bounds.npy")
            },
            "3 images",
        ),
        (
            "NaN pose",
            |d| {
                let npy = d.join("poses_bounds.npy");
                let mut bytes = std::fs::read(&npy).unwrap();
                // Row 1's first value (rows of 17 float64s end the file).
                let at = bytes.len() - 3 * 17 * 8;
                bytes[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
                std::fs::write(&npy, bytes).unwrap();
                npy
            },
            "",
        ),
        (
            "zero registered images",
            |d| {
                for i in 0..4 {
                    std::fs::remove_file(d.join("images").join(format!("frame_{i:02}.png")))
                        .unwrap();
                }
                let npy = d.join("poses_bounds.npy");
                std::fs::write(&npy, npy_rows(&[])).unwrap();
                npy
            },
            "",
        ),
    ];
    let writers: [(&str, Writer, &[Case]); 3] = [
        ("colmap", write_colmap_text, &colmap),
        ("nerfstudio", write_nerfstudio, &nerfstudio),
        ("llff", write_llff, &llff),
    ];
    for (format, write, breakages) in writers {
        for (i, (what, breakage, says)) in breakages.iter().enumerate() {
            let dir = root.path().join(format!("{format}_{i}"));
            write(&lego, &dir);
            let named = breakage(&dir);
            let out = root.path().join(format!("out_{format}_{i}"));
            let ckpt = format!("training.checkpoint_path={}", out.join("ck").display());
            let out_dir = out.join("images");
            let args = [
                "train",
                "--config",
                "nerf_scene",
                "--data-dir",
                dir.to_str().unwrap(),
                "--out-dir",
                out_dir.to_str().unwrap(),
                &ckpt,
            ];
            let err = error_line(&common::nerf(&args));
            eprintln!("{format}, {what}: {err}");
            assert!(
                err.contains(&named.display().to_string()) && err.contains(says),
                "{format}, {what}: {err}"
            );
            assert!(!out.exists(), "{format}, {what}: wrote {}", out.display());
        }
    }
}
