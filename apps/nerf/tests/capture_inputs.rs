//! Captures as users have them: masks, the text and binary forms of one COLMAP model, and
//! each loader's bad input, on captures of the first lego training views
//! (`common::lego_capture`).

mod common;

use common::lego_capture::*;

use std::path::{Path, PathBuf};

use nerf::io::dataset::{Dataset, Split};

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
    edit_transforms(dir, |json| {
        for frame in json["frames"].as_array_mut().unwrap() {
            let name = frame["file_path"]
                .as_str()
                .unwrap()
                .replace("images/", "masks/");
            frame["mask_path"] = serde_json::json!(name);
        }
    });
}

#[test]
fn masks_ignore_pixels_in_training_and_scoring_and_bad_ones_are_named() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let cut = lego.size.0 / 2;
    // nerfstudio: mask_path per frame.
    let ns = scratch.path("nerfstudio");
    write_nerfstudio(lego, &ns);
    write_masks(&ns, FRAMES, lego.size, cut, false);
    add_mask_paths(&ns);
    // COLMAP: masks/ beside images/, and the ignored halves of the photos painted over.
    let painted = scratch.colmap_text("colmap");
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

    let scene = scratch.tiny_scene("nerf_scene_bounded", 1);
    let run = |command: &str, dir: &Path| {
        let mut args = scene.args(command, dir, &[]);
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
    let plain = scratch.colmap_text("plain");
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
    let fresh = scratch.path("fresh.safetensors");
    let fresh_arg = format!("training.checkpoint_path={}", fresh.display());
    let bad_size = plain.join("masks").join("frame_03.png");
    image::GrayImage::new(7, 5).save(&bad_size).unwrap();
    let missing = plain.join("masks").join("frame_05.png");
    for (file, says) in [(&bad_size, "is 7x5"), (&missing, "")] {
        let more = [
            "data.image_size=[24,24]",
            "training.num_epochs=1",
            &fresh_arg,
        ];
        let args = common::data_args("train", "nerf_scene_bounded", &plain, &more);
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
fn an_object_photographed_alone_is_sampled_over_its_hull_at_training_and_eval() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    // Lego's views keep their alpha: the object alone.
    let dir = scratch.colmap_text("alone");
    let scene = scratch.tiny_scene("nerf_scene", 1);
    let log = common::stderr(&scene.run_ok("train", &dir, &[]));
    assert!(log.contains("the photos outline an object"), "{log}");
    let path = &scene.checkpoint;
    let meta = nerf::io::checkpoint::read_metadata(path).unwrap();
    let stored = nerf::io::checkpoint::SAMPLE_DEPTHS.read(&meta, path);
    let (near, far) = stored.unwrap().expect("the narrowed depths are stored");
    // The cameras stand at most 1 from the centre, lego within about a third of that: the
    // hull's depths lie well inside nerf_scene's 0.02 to 2.8.
    assert!(near > 0.3 && far < 2.0 && near < far, "{near} {far}");
    // The hash grid and the occupancy grid cover the cube round the hull: round the
    // cameras' focus (the origin), and well inside the unit cube the hull is carved from.
    assert!(
        log.contains("cover the cube round the object's hull"),
        "{log}"
    );
    let cube = nerf::io::checkpoint::OBJECT_BOX.read(&meta, path);
    let cube = cube.unwrap().expect("the object's cube is stored");
    let side = cube[3] - cube[0];
    assert!(
        (0..3).all(|k| cube[k] < 0.0 && cube[k + 3] > 0.0),
        "{cube:?}"
    );
    assert!(side > 0.1 && side < 1.0, "{cube:?}");
    // Eval reads the model over the same cube (a field of another box would be refused).
    let mut args = scene.args("eval", &dir, &[]);
    args.extend(["--split", "test"]);
    let out = common::nerf_ok(&args);
    assert!(String::from_utf8_lossy(&out.stdout).contains("PSNR mean"));
    // Photos with no alpha and no masks (a room): nothing is narrowed, nothing stored.
    let opaque = scratch.colmap_text("opaque");
    for entry in std::fs::read_dir(opaque.join("images")).unwrap() {
        let photo = entry.unwrap().path();
        let rgb = image::open(&photo).unwrap().to_rgb8();
        image::DynamicImage::ImageRgb8(rgb).save(&photo).unwrap();
    }
    std::fs::remove_file(path).unwrap();
    let log = common::stderr(&scene.run_ok("train", &opaque, &[]));
    assert!(!log.contains("outline an object"), "{log}");
    let meta = nerf::io::checkpoint::read_metadata(path).unwrap();
    assert!(!meta.contains_key(nerf::io::checkpoint::SAMPLE_DEPTHS.key));
    assert!(!meta.contains_key(nerf::io::checkpoint::OBJECT_BOX.key));
}

#[test]
fn masks_that_outline_an_object_train_it_alone_shown_over_the_backdrop_they_leave_out() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    // A turntable's photos: lego over a plain backdrop, opaque, and masks of its silhouette.
    let backdrop = [64u8, 128, 192];
    let dir = scratch.colmap_text("turntable");
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    for i in 0..FRAMES {
        let name = format!("frame_{i:02}.png");
        let photo = dir.join("images").join(&name);
        let rgba = image::open(&photo).unwrap().to_rgba8();
        let mask = image::GrayImage::from_fn(rgba.width(), rgba.height(), |x, y| {
            image::Luma([if rgba.get_pixel(x, y)[3] > 127 {
                255
            } else {
                0
            }])
        });
        mask.save(dir.join("masks").join(&name)).unwrap();
        let rgb = image::RgbImage::from_fn(rgba.width(), rgba.height(), |x, y| {
            let p = rgba.get_pixel(x, y);
            let a = f32::from(p[3]) / 255.0;
            image::Rgb(std::array::from_fn(|c| {
                (f32::from(p[c]) * a + f32::from(backdrop[c]) * (1.0 - a)).round() as u8
            }))
        });
        rgb.save(&photo).unwrap();
    }
    let scene = scratch.tiny_scene("nerf_scene", 1);
    let log = common::stderr(&scene.run_ok("train", &dir, &[]));
    assert!(
        log.contains("outline an object") && log.contains("trained as its alpha"),
        "{log}"
    );
    assert!(log.contains("the mean colour the masks leave out"), "{log}");
    let path = &scene.checkpoint;
    let meta = nerf::io::checkpoint::read_metadata(path).unwrap();
    // The backdrop as the masks leave it out: at 24×24 the pixels a resize mixes with the
    // object, left out as well, are a good part of them, so lego's colours enter (measured
    // up to 0.09 off).
    let stored = nerf::io::checkpoint::BACKGROUND
        .read(&meta, path)
        .unwrap()
        .unwrap();
    for (got, want) in stored.iter().zip(backdrop) {
        assert!((got - f32::from(want) / 255.0).abs() < 0.12, "{stored:?}");
    }
    assert!(nerf::io::checkpoint::OBJECT_BOX
        .read(&meta, path)
        .unwrap()
        .is_some());
    let out = scene.run_ok("eval", &dir, &["--split", "test"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let shown = format!("on {}", nerf::core::image::colour_name(stored));
    assert!(
        stdout.contains("PSNR mean") && stdout.contains(&shown),
        "{stdout}"
    );
    // Exports read the model over its cube as well (a field of another box is refused).
    let depth = scratch.path("depth");
    let depth_arg = depth.to_str().unwrap();
    let mut args = vec!["export", "depth", "--split", "test", "--out", depth_arg];
    args.extend(scene.args("", &dir, &[]).into_iter().skip(1));
    let log = common::stderr(&common::nerf_ok(&args));
    assert!(!files_of(&depth).is_empty(), "{log}");
}

#[test]
fn one_checkpoint_renders_the_same_images_from_the_text_and_binary_colmap_model() {
    let Some(scratch) = lego_root(FRAMES) else {
        return;
    };
    let lego = &scratch.lego;
    let text = scratch.colmap_text("text");
    let binary = scratch.path("binary");
    write_colmap_binary(lego, &text, &binary);
    assert!(binary.join("sparse/0/images.bin").is_file());
    let scene = scratch.tiny_scene("nerf_scene_bounded", 1);
    scene.run_ok("train", &text, &[]);
    let (a, b) = (scratch.path("a"), scratch.path("b"));
    for (dir, saved) in [(&text, &a), (&binary, &b)] {
        let saved = saved.to_str().unwrap();
        scene.run_ok("eval", dir, &["--split", "test", "--save-images", saved]);
    }
    assert_eq!(files_of(&a).len(), 2);
    assert_eq!(files_of(&a), files_of(&b));
}

/// The COLMAP model file `name` of the capture `d` (`sparse/0/name`).
fn model_file(d: &Path, name: &str) -> PathBuf {
    d.join("sparse").join("0").join(name)
}

/// Replaces `from` by `to` in the text file `path` (once, which must match).
fn edit(path: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{}: no {from}", path.display());
    std::fs::write(path, text.replacen(from, to, 1)).unwrap();
}

#[test]
fn each_loaders_bad_input_is_one_line_naming_the_file_and_nothing_is_written() {
    let Some(scratch) = lego_root(4) else {
        return;
    };
    let lego = &scratch.lego;
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
            // COLMAP's THIN_PRISM_FISHEYE model (fx fy cx cy k1 k2 p1 p2 k3 k4 sx1 sy1), which
            // no lens model here reads.
            |d| {
                edit_line(
                    model_file(d, "cameras.txt"),
                    |l| l.contains("PINHOLE"),
                    |line| line.replace("PINHOLE", "THIN_PRISM_FISHEYE") + " 0 0 0 0 0 0 0 0",
                )
            },
            "THIN_PRISM_FISHEYE",
        ),
        ("image listed but absent", absent_image, ""),
        (
            "NaN pose",
            |d| {
                edit_line(
                    model_file(d, "images.txt"),
                    |l| l.starts_with("2 "),
                    |line| {
                        let mut fields: Vec<&str> = line.split(' ').collect();
                        fields[5] = "nan";
                        fields.join(" ")
                    },
                )
            },
            "",
        ),
        (
            "zero registered images",
            |d| {
                let images = model_file(d, "images.txt");
                std::fs::write(&images, "# no images\n").unwrap();
                images
            },
            "",
        ),
    ];
    let nerfstudio: [Case; 8] = [
        (
            "one photo listed twice, with two poses",
            |d| {
                edit_transforms(d, |v| {
                    v["frames"][2]["file_path"] = v["frames"][1]["file_path"].clone()
                })
            },
            "frame 2 lists",
        ),
        (
            "a photo in train_filenames and test_filenames",
            |d| {
                edit_transforms(d, |v| {
                    let names: Vec<_> =
                        (0..4).map(|i| format!("images/frame_{i:02}.png")).collect();
                    v["train_filenames"] = serde_json::json!(names);
                    v["test_filenames"] = serde_json::json!(["images/frame_02.png"]);
                })
            },
            "images/frame_02.png is in both train_filenames and test_filenames",
        ),
        (
            "a width that is not a whole number of pixels",
            |d| edit_transforms(d, |v| v["w"] = serde_json::json!(400.5)),
            "w = 400.5 is not a whole number of pixels",
        ),
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
            |d| edit_transforms(d, |v| v["frames"] = serde_json::json!([])),
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
            let dir = scratch.path(&format!("{format}_{i}"));
            write(lego, &dir);
            let named = breakage(&dir);
            let out = scratch.path(&format!("out_{format}_{i}"));
            let ckpt = format!("training.checkpoint_path={}", out.join("ck").display());
            let out_dir = out.join("images");
            let more = ["--out-dir", out_dir.to_str().unwrap(), &ckpt];
            let args = common::data_args("train", "nerf_scene_bounded", &dir, &more);
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
