//! Cameras that cannot be right, through each loader (COLMAP text and binary, nerfstudio,
//! instant-ngp, LLFF): finite but impossible focal lengths, principal points and distortions, a camera of
//! another shape than its photos, centres too far from the origin to resolve, and a lone
//! camera. Each is one `error:` line naming the file (and the camera or frame) with the rule
//! it broke, exit 1, and nothing written (`core::camera::checks`, docs/reliability.md#captures).

mod common;

use std::path::{Path, PathBuf};

use common::lego_capture::*;
use nerf::io::dataset::{CaptureOrbit, SceneTransform};

/// Replaces the camera line of `dir`'s COLMAP `cameras.txt` by `line(w, h, f)` and returns the
/// file.
fn colmap_camera(dir: &Path, line: impl Fn(f64, f64, f64) -> String) -> PathBuf {
    let cameras = dir.join("sparse").join("0").join("cameras.txt");
    edit_line(
        cameras,
        |l| l.contains("PINHOLE"),
        |old| {
            let fields: Vec<f64> = old.split(' ').skip(2).map(|v| v.parse().unwrap()).collect();
            line(fields[0], fields[1], fields[2])
        },
    )
}

/// Sets the focal length of each of the `rows` rows of `dir/poses_bounds.npy` to `focal`;
/// returns the file.
fn llff_focal(dir: &Path, rows: usize, focal: f64) -> PathBuf {
    let npy = dir.join("poses_bounds.npy");
    let mut bytes = std::fs::read(&npy).unwrap();
    for r in 0..rows {
        // Row r's value 14 (hwf's focal, the third row's last column).
        let at = bytes.len() - (rows - r) * 17 * 8 + 14 * 8;
        bytes[at..at + 8].copy_from_slice(&focal.to_le_bytes());
    }
    std::fs::write(&npy, bytes).unwrap();
    npy
}

/// Trains on `dir`, expecting one error line that names `named` and says every one of `says`;
/// nothing may be written.
fn refused(root: &Path, name: &str, dir: &Path, named: &Path, says: &[&str]) {
    let out = root.join(format!("out_{name}"));
    let ckpt = format!("training.checkpoint_path={}", out.join("ck").display());
    let args = common::data_args("train", "nerf_scene", dir, &[&ckpt]);
    let err = error_line(&common::nerf(&args));
    eprintln!("{name}: {err}");
    assert!(err.contains(&named.display().to_string()), "{name}: {err}");
    for s in says {
        assert!(err.contains(s), "{name}: {err} (expected {s:?})");
    }
    // Short numbers, never hundreds of digits.
    assert!(err.len() < 400, "{name}: {err}");
    assert!(!out.exists(), "{name}: wrote {}", out.display());
}

#[test]
fn cameras_that_cannot_be_right_are_refused_by_every_loader() {
    let Some(scratch) = lego_root(4) else {
        return;
    };
    let lego = &scratch.lego;
    let root = scratch.root.path();
    let fresh = |name: &str, write: fn(&Lego, &Path)| {
        let dir = root.join(name);
        write(lego, &dir);
        dir
    };

    // COLMAP text: each intrinsic rule, named by the file and the camera id.
    type Line = fn(f64, f64, f64) -> String;
    let colmap: [(&str, Line, &[&str]); 6] = [
        (
            "focal 1e-300",
            |w, h, _| format!("1 PINHOLE {w} {h} 1e-300 1e-300 {} {}", w / 2.0, h / 2.0),
            &["camera 1", "field of view of 180°"],
        ),
        (
            "focal 1e308",
            |w, h, _| format!("1 PINHOLE {w} {h} 1e308 1e308 {} {}", w / 2.0, h / 2.0),
            &["camera 1", "focal length 1e308 px"],
        ),
        (
            "principal point 1e300",
            |w, h, f| format!("1 PINHOLE {w} {h} {f} {f} 1e300 {}", h / 2.0),
            &["camera 1", "cx = 1e300"],
        ),
        (
            "distortion 1e308",
            |w, h, f| {
                format!(
                    "1 OPENCV {w} {h} {f} {f} {} {} 1e308 0 0 0",
                    w / 2.0,
                    h / 2.0
                )
            },
            &["camera 1", "not invertible"],
        ),
        (
            "a 400x100 camera for square photos",
            |w, h, f| format!("1 PINHOLE {w} {} {f} {f} {} {}", h / 4.0, w / 2.0, h / 8.0),
            &["frame_", "aspect"],
        ),
        (
            "a 2^31 camera for its photos",
            |w, _, f| {
                let s = 2f64.powi(31) / w;
                let side = 2u64.pow(31);
                format!(
                    "1 PINHOLE {side} {side} {} {} {} {}",
                    f * s,
                    f * s,
                    side / 2,
                    side / 2
                )
            },
            &["frame_", "64 times"],
        ),
    ];
    for (i, (what, line, says)) in colmap.iter().enumerate() {
        let dir = fresh(&format!("colmap_{i}"), write_colmap_text);
        let cameras = colmap_camera(&dir, line);
        // The size rules name the photo; the intrinsic rules the cameras file.
        let named = if says[0] == "frame_" {
            dir.join("images")
        } else {
            cameras
        };
        refused(root, &format!("colmap, {what}"), &dir, &named, says);
        // The same model as COLMAP's binary files.
        let binary = root.join(format!("colmap_binary_{i}"));
        write_colmap_binary(lego, &dir, &binary);
        let sparse = binary.join("sparse").join("0");
        let named = match says[0] {
            "frame_" => binary.join("images"),
            _ => sparse.join("cameras.bin"),
        };
        refused(
            root,
            &format!("colmap binary, {what}"),
            &binary,
            &named,
            says,
        );
    }

    // nerfstudio: the frame's intrinsics, the photo's shape, centres far from the origin, and
    // a lone camera.
    type Change = fn(&mut serde_json::Value);
    let nerfstudio: [(&str, Change, &[&str]); 5] = [
        (
            "fl_x 1e-300",
            |v| {
                v["fl_x"] = serde_json::json!(1e-300);
                v["fl_y"] = serde_json::json!(1e-300);
            },
            &["frame 0", "field of view"],
        ),
        (
            "k1 1e308",
            |v| v["k1"] = serde_json::json!(1e308),
            &["frame 0", "not invertible"],
        ),
        (
            "h = 100 for square photos",
            |v| {
                v["h"] = serde_json::json!(100);
                v["cy"] = serde_json::json!(50);
            },
            &["frame_", "aspect"],
        ),
        (
            "centres shifted by 1e13",
            |v| {
                for frame in v["frames"].as_array_mut().unwrap() {
                    let x = frame["transform_matrix"][0][3].as_f64().unwrap();
                    frame["transform_matrix"][0][3] = serde_json::json!(x + 1e13);
                }
            },
            &["origin", "e12 from the origin"],
        ),
        (
            "one camera",
            |v| {
                let first = v["frames"][0].clone();
                v["frames"] = serde_json::json!([first]);
            },
            &["one point", "1 camera", "frame_00.png"],
        ),
    ];
    for (i, (what, change, says)) in nerfstudio.iter().enumerate() {
        let dir = fresh(&format!("nerfstudio_{i}"), write_nerfstudio);
        let json = edit_transforms(&dir, change);
        let named = match says[0] {
            "frame_" => dir.join("images"),
            "origin" | "one point" => dir.clone(),
            _ => json,
        };
        refused(root, &format!("nerfstudio, {what}"), &dir, &named, says);
    }

    // instant-ngp: a field of view of 179.9° (inside instant-ngp's (0, π), not a lens's).
    let dir = root.join("ngp");
    write_colmap2nerf(lego, &dir, None);
    let json = edit_transforms(&dir, |v| {
        v.as_object_mut().unwrap().remove("fl_x");
        v.as_object_mut().unwrap().remove("fl_y");
        v["camera_angle_x"] = serde_json::json!(179.9f64.to_radians());
    });
    refused(root, "instant-ngp, 179.9°", &dir, &json, &["field of view"]);

    // LLFF: a focal length of 1e-300 in poses_bounds.npy.
    let dir = fresh("llff", write_llff);
    let npy = llff_focal(&dir, lego.views.len(), 1e-300);
    refused(
        root,
        "llff, focal 1e-300",
        &dir,
        &npy,
        &["row 0", "field of view"],
    );
}

#[test]
fn checkpoint_metadata_that_cannot_be_right_is_refused_naming_the_checkpoint() {
    let Some(scratch) = lego_root(9) else {
        return;
    };
    let dir = scratch.colmap_text("capture");
    let scene = TinyScene::new("nerf_scene_bounded", scratch.path("model.safetensors"), 1);
    scene.run_ok("train", &dir, &[]);
    let ckpt = &scene.checkpoint;
    let (_, info) = nerf::io::checkpoint::load(ckpt, &candle_core::Device::Cpu).unwrap();
    let orbit = info
        .capture_orbit
        .expect("a capture checkpoint stores its orbit");
    let transform = info.scene_transform.expect("and its normalisation");
    // Each bad value, the command that reads it, and what the error must say.
    type Edit = Box<dyn Fn(&mut nerf::io::checkpoint::CheckpointInfo)>;
    let with_orbit =
        |orbit: CaptureOrbit| -> Edit { Box::new(move |i| i.capture_orbit = Some(orbit)) };
    let with_transform = |transform: SceneTransform| -> Edit {
        Box::new(move |i| i.scene_transform = Some(transform))
    };
    let scaled = SceneTransform {
        scale: 1e300,
        ..transform
    };
    let cases: Vec<(&str, Edit, &str, &str)> = vec![
        (
            "orbit radius 1e300",
            with_orbit(CaptureOrbit {
                radius: 1e300,
                ..orbit
            }),
            "render",
            "the orbit's radius 1e300 is beyond 100",
        ),
        (
            "orbit height 1e308",
            with_orbit(CaptureOrbit {
                height: 1e308,
                ..orbit
            }),
            "render",
            "the orbit's height 1e308 is beyond 100",
        ),
        (
            "orbit focal 1e-300",
            with_orbit(CaptureOrbit {
                focal: [1e-300, 2.0],
                ..orbit
            }),
            "render",
            "NDC focal length of 1e-300",
        ),
        (
            "scene scale 1e100",
            with_transform(scaled),
            "eval",
            "stored in the checkpoint (metadata scene_transform) puts a camera",
        ),
        (
            "scene scale 1e100, resumed",
            with_transform(scaled),
            "train",
            "stored in the checkpoint (metadata scene_transform) puts a camera",
        ),
    ];
    for (n, (what, edit, command, says)) in cases.into_iter().enumerate() {
        let bad = scratch.path(&format!("bad_{n}.safetensors"));
        resave_checkpoint(ckpt, &bad, edit);
        let before = std::fs::read(&bad).unwrap();
        let out = scratch.path(&format!("out_{n}"));
        let ckpt_arg = format!("training.checkpoint_path={}", bad.display());
        // `render` and `view` read the stored path through the same function
        // (`render::scene_frame::render_cameras` of the binary): `render` stands for both.
        let mut args = vec![command, "--config", "nerf_scene_bounded"];
        if command != "render" {
            args.extend(["--data-dir", dir.to_str().unwrap()]);
        }
        match command {
            "render" => args.extend(["--out-dir", out.to_str().unwrap()]),
            "train" => args.push("training.num_epochs=2"),
            _ => {}
        }
        args.push(&ckpt_arg);
        args.extend(["data.image_size=[24,24]", "sampler.n_pts_per_ray=32"]);
        let err = error_line(&common::nerf(&args));
        eprintln!("{what} ({command}): {err}");
        assert!(err.contains(says), "{what}: {err} (expected {says:?})");
        assert!(
            err.contains(&bad.display().to_string()) || err.contains("checkpoint"),
            "{what}: {err}"
        );
        assert!(err.len() < 400, "{what}: {err}");
        assert!(!out.exists(), "{what}: wrote {}", out.display());
        assert_eq!(
            std::fs::read(&bad).unwrap(),
            before,
            "{what}: the checkpoint changed"
        );
    }
}
