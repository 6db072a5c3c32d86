//! The typed errors of the library's four boundaries — camera, checkpoint, config and dataset —
//! matched by variant, and their text: the one line the `nerf` binary printed before they were
//! typed, printed once (a typed error has no source that repeats it).

mod common;

use std::path::Path;

use candle_core::{Device, Tensor};
use nerf::config::{apply_override, Config, ConfigError};
use nerf::core::camera::checks::{check_intrinsics, check_photo_size};
use nerf::core::lens::LensDistortion;
use nerf::core::term::error_line;
use nerf::io::checkpoint::{self, CheckpointError, CheckpointInfo};
use nerf::io::checkpoint_file;
use nerf::io::dataset::{read_split, Dataset, DatasetError, Split};
use nerf::train::model::TrainModel;
use nerf::{CameraError, PerspectiveCamera};

/// `error` as the binary prints it (after `error: `): its chain through `anyhow`, one line.
fn printed<E: Into<anyhow::Error>>(error: E) -> String {
    error_line(error.into().as_ref())
}

/// Checks that `error` displays `line` and that the binary prints exactly that (its text
/// once, not followed by a source that repeats it).
fn says<E>(error: E, line: &str)
where
    E: std::error::Error + Send + Sync + 'static,
{
    assert_eq!(error.to_string(), line);
    assert_eq!(printed(error), line);
}

/// Asserts that the error `$e` matches the pattern (and guard) after it, printing it if not.
macro_rules! assert_is {
    ($e:expr, $($pattern:tt)+) => {
        assert!(matches!($e, $($pattern)+), "{:?}", $e)
    };
}

/// The text of `error`, checked to be what the binary prints.
fn text<E>(error: E) -> String
where
    E: std::error::Error + Send + Sync + 'static,
{
    let text = error.to_string();
    assert_eq!(printed(error), text);
    text
}

#[test]
fn camera_checks_return_camera_errors() {
    let none = LensDistortion::NONE;
    let e = check_intrinsics((64, 48), [1e-300, 50.0], [32.0, 24.0], &none).unwrap_err();
    assert_is!(
        e,
        CameraError::FieldOfView {
            axis: "x",
            fisheye: false,
            ..
        }
    );
    says(
        e,
        "a field of view of 180° across x (64 px at focal length 1e-300 px) is not a lens's: \
         it must be 0.5° to 179°",
    );
    let e = check_intrinsics((64, 48), [50.0, 50.0], [3200.0, 24.0], &none).unwrap_err();
    assert_is!(e, CameraError::PrincipalPoint { axis: "cx", value, .. } if value == 3200.0);
    says(
        e,
        "the principal point's cx = 3200 px lies outside the image (0 to 64 px) by more than 25% \
         of its side",
    );
    let folding = LensDistortion::polynomial([-0.5, 0.0, 0.0, 0.0], [0.0; 2]);
    let e = check_intrinsics((400, 400), [400.0; 2], [200.0; 2], &folding).unwrap_err();
    assert_is!(e, CameraError::Distortion { .. });
    assert!(text(e).starts_with("the lens distortion is not "));
    let e = check_photo_size((400, 100), (400, 400)).unwrap_err();
    assert_is!(
        e,
        CameraError::PhotoSize {
            camera: (400, 100),
            photo: (400, 400),
            ..
        }
    );
    says(
        e,
        "the camera is 400x100 but its photo is 400x400: a camera must have its photo's size or \
         its aspect (here 4.000 against 1.000)",
    );
    // Validation of a camera: a non-finite pose, a zero focal length.
    let mut camera = nerf::surround_cameras(3.0, 1, glam::DVec3::Y, 1.0)[0];
    camera.t[1] = f64::NAN;
    let e = camera.validate().unwrap_err();
    assert_is!(e, CameraError::NotFinite { .. });
    says(
        e,
        "camera has a non-finite value in R, T, focal length or principal point",
    );
    let camera = PerspectiveCamera::new(camera.r, [0.0, 0.0, 3.0], 1.0);
    let camera = PerspectiveCamera {
        focal: [0.0, 1.0],
        ..camera
    };
    let e = camera.validate().unwrap_err();
    assert_is!(
        e,
        CameraError::FocalLength {
            focal: [0.0, 1.0],
            ..
        }
    );
    says(e, "camera focal length must be non-zero");
}

/// Parameter names and shapes, in a model's order.
type Shapes = Vec<(String, Vec<usize>)>;

/// The built-in `nerf_lego` config's model and the parameters it expects.
fn nerf_lego() -> (std::sync::Arc<dyn nerf::FieldSpec>, Shapes) {
    let spec = Config::load("nerf_lego", &[])
        .unwrap()
        .field_spec()
        .unwrap();
    let shapes = spec.seeded(0, &Device::Cpu).unwrap().parameter_shapes();
    (spec, shapes)
}

#[test]
fn checkpoint_readers_return_checkpoint_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let device = Device::Cpu;
    // Missing.
    let missing = d.join("missing.safetensors");
    let e = checkpoint::load(&missing, &device).unwrap_err();
    assert!(matches!(&e, CheckpointError::NotFound { path, .. } if *path == missing));
    let line = format!(
        "cannot read checkpoint {}: No such file or directory (os error 2)",
        missing.display()
    );
    says(e, &line);
    // Missing where the config's own training.checkpoint_path points, and a directory of none.
    let configured = d.join("configured.safetensors");
    let key = format!("training.checkpoint_path={}", configured.display());
    let config = Config::load("nerf_lego", &[key]).unwrap();
    let e = config.ensure_checkpoint(&configured).unwrap_err();
    assert!(matches!(&e, CheckpointError::NotFound { path, .. } if *path == configured));
    assert!(text(e).contains("training.checkpoint_path"));
    let e = checkpoint_file::ensure_checkpoint_file(d).unwrap_err();
    assert_is!(&e, CheckpointError::NotFound { path, .. } if path == d);
    // Not a checkpoint.
    let garbage = d.join("garbage.safetensors");
    std::fs::write(&garbage, b"hello world, not a checkpoint").unwrap();
    let e = checkpoint_file::load(&garbage, &Vec::new(), &device).unwrap_err();
    assert_is!(e, CheckpointError::Format { .. });
    let line = format!(
        "checkpoint {} is corrupt or not a checkpoint (neither safetensors nor a PyTorch file)",
        garbage.display()
    );
    says(e, &line);
    // A checkpoint of another model: a parameter missing, or of another shape.
    let (spec, shapes) = nerf_lego();
    let (first, shape) = shapes[0].clone();
    let other = d.join("other.safetensors");
    let w = Tensor::zeros(3, candle_core::DType::F32, &device).unwrap();
    checkpoint::save(
        &other,
        &[("w".into(), w.clone())],
        CheckpointInfo::default(),
    )
    .unwrap();
    let e = TrainModel::from_checkpoint(&*spec, &other, &device)
        .err()
        .unwrap();
    assert_is!(&e, CheckpointError::MissingParameter { name, .. } if *name == first);
    let line = format!(
        "checkpoint {} lacks tensor {first} (is it a nerf checkpoint of this config's sizes?)",
        other.display()
    );
    says(e, &line);
    checkpoint::save(&other, &[(first.clone(), w)], CheckpointInfo::default()).unwrap();
    let e = TrainModel::from_checkpoint(&*spec, &other, &device)
        .err()
        .unwrap();
    assert_is!(
        &e,
        CheckpointError::Shape { name, expected, found, .. }
            if *name == first && *expected == shape && *found == [3]
    );
    let line = format!(
        "checkpoint {}: tensor {first} has shape [3] but the config needs {shape:?}",
        other.display()
    );
    says(e, &line);
    // Metadata out of bounds.
    let info = CheckpointInfo {
        epoch: 1 << 30,
        ..CheckpointInfo::default()
    };
    checkpoint::save(&other, &[], info).unwrap();
    let e = checkpoint::load(&other, &device).unwrap_err();
    assert_is!(&e, CheckpointError::Metadata { key, .. } if key == "epoch");
    let line = format!(
        "checkpoint {}: metadata epoch = 1073741824 is past the most a run can have (1048576); \
         the file is corrupt or crafted",
        other.display()
    );
    says(e, &line);
    // A directory holding several.
    let several = d.join("several");
    for name in ["a.safetensors", "b.safetensors"] {
        checkpoint::save(&several.join(name), &[], CheckpointInfo::default()).unwrap();
    }
    let e = checkpoint_file::resolve(&several, "nerf_lego").unwrap_err();
    assert_is!(&e, CheckpointError::Ambiguous { found, .. } if found.len() == 2);
    let line = format!(
        "checkpoint directory {} holds several checkpoints (a.safetensors, b.safetensors); \
         name one with --checkpoint",
        several.display()
    );
    says(e, &line);
}

#[test]
fn a_checkpoint_of_another_hash_grid_layout_is_refused() {
    // Two hash grids of the same parameter shapes, read at other resolutions: the second
    // would load the first's table and render garbage.
    let dir = tempfile::tempdir().unwrap();
    let device = Device::Cpu;
    let small = |max_resolution: u32| {
        let overrides = [
            "implicit_function.n_levels=3".to_string(),
            "implicit_function.log2_hashmap_size=8".to_string(),
            format!("implicit_function.max_resolution={max_resolution}"),
        ];
        Config::load("nerf_lego_ngp", &overrides)
            .unwrap()
            .field_spec()
            .unwrap()
    };
    let (trained, other) = (small(64), small(32));
    let model = trained.seeded(3, &device).unwrap();
    let layout = model.layout().unwrap();
    assert_ne!(
        Some(layout.clone()),
        other.seeded(3, &device).unwrap().layout()
    );
    let path = dir.path().join("grid.safetensors");
    let info = CheckpointInfo {
        field_layout: Some(layout.clone()),
        ..CheckpointInfo::default()
    };
    checkpoint::save(&path, &checkpoint::model_tensors(model.varmap()), info).unwrap();
    let loaded = TrainModel::from_checkpoint(&*trained, &path, &device).unwrap();
    assert_eq!(loaded.info.field_layout.as_deref(), Some(layout.as_str()));
    let e = TrainModel::from_checkpoint(&*other, &path, &device)
        .err()
        .unwrap();
    assert_is!(&e, CheckpointError::Metadata { key, .. } if key == "field_layout");
    let line = text(e);
    assert!(
        line.contains("resolution 16 to 64") && line.contains("resolution 16 to 32"),
        "{line}"
    );
    // A checkpoint that stored no layout (older ones) loads as it did.
    checkpoint::save(
        &path,
        &checkpoint::model_tensors(model.varmap()),
        CheckpointInfo::default(),
    )
    .unwrap();
    assert!(TrainModel::from_checkpoint(&*other, &path, &device).is_ok());
}

#[test]
fn config_loaders_return_config_errors() {
    let e = Config::load("no_such_config", &[]).unwrap_err();
    assert_is!(&e, ConfigError::NotFound { name, .. } if name == "no_such_config");
    assert!(text(e).starts_with(
        "config `no_such_config` not found (not a file, not configs/no_such_config.yaml; \
         built-in configs: box, "
    ));
    let e = Config::load("/nonexistent.yaml", &[]).unwrap_err();
    assert_is!(e, ConfigError::NotFound { .. });
    says(e, "config file /nonexistent.yaml not found");
    let e = Config::from_yaml("data: [1, 2", &[]).unwrap_err();
    assert_is!(e, ConfigError::Syntax { .. });
    says(
        e,
        "malformed YAML: did not find expected ',' or ']' at line 2 column 1, while parsing a \
         flow sequence at line 1 column 7",
    );
    // A bad value, blamed on the override that gave it or the file line that holds it.
    let o = ["sampler.n_pts_per_ray=0".to_string()];
    let e = Config::load("box", &o).unwrap_err();
    assert_is!(&e, ConfigError::Invalid { key, .. } if key == "sampler.n_pts_per_ray");
    says(
        e,
        "override `sampler.n_pts_per_ray=0`: sampler.n_pts_per_ray: must be 1 to 16384 (got 0)",
    );
    let o = ["sampler.n_pts_per_ray=x".to_string()];
    let e = Config::load("box", &o).unwrap_err();
    assert_is!(e, ConfigError::Invalid { .. });
    says(
        e,
        "override `sampler.n_pts_per_ray=x`: sampler.n_pts_per_ray: invalid type: string \"x\", \
         expected a whole number",
    );
    let (_dir, file) = common::scratch("bad.yaml");
    let text = nerf::config::config_text("box").unwrap().0;
    let text = text.replace("n_pts_per_ray: 64", "n_pts_per_ray: 0");
    std::fs::write(&file, &text).unwrap();
    let line = 1 + text
        .lines()
        .position(|l| l.contains("n_pts_per_ray"))
        .unwrap();
    let e = Config::load(file.to_str().unwrap(), &[]).unwrap_err();
    assert_is!(e, ConfigError::Invalid { .. });
    let expected = format!(
        "config {}, line {line}: sampler.n_pts_per_ray: must be 1 to 16384 (got 0)",
        file.display()
    );
    says(e, &expected);
    // An override that does not parse.
    let e = Config::load("box", &["x".to_string()]).unwrap_err();
    assert_is!(&e, ConfigError::Override { assignment, .. } if assignment == "x");
    says(e, "override `x`: not of the form key.sub=value");
    let mut root = serde_yaml_ng::Value::Null;
    let e = apply_override(&mut root, "a..b=1").unwrap_err();
    assert_is!(e, ConfigError::Override { .. });
    says(e, "override `a..b=1`: empty key");
}

/// A nerfstudio capture of 9 photos `images/f{i}.png`, 64×48 PNGs, in `dir`, whose
/// intrinsics are the JSON keys `intrinsics`.
fn nerfstudio_capture(dir: &Path, intrinsics: &str) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let photo = png();
    let frames: Vec<String> = (0..9)
        .map(|i| {
            std::fs::write(dir.join(format!("images/f{i}.png")), &photo).unwrap();
            format!(
                r#"{{"file_path": "images/f{i}.png", "transform_matrix": [[1, 0, 0, {i}], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]}}"#
            )
        })
        .collect();
    let json = format!(
        r#"{{"camera_model": "OPENCV", {intrinsics}, "w": 64, "h": 48, "frames": [{}]}}"#,
        frames.join(", ")
    );
    std::fs::write(dir.join("transforms.json"), json).unwrap();
}

/// A 64×48 PNG.
fn png() -> Vec<u8> {
    let mut bytes = Vec::new();
    image::RgbImage::new(64, 48)
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .unwrap();
    bytes
}

#[test]
fn dataset_loaders_return_dataset_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A folder of something else.
    let e = read_split(d, Split::Test).unwrap_err();
    assert_is!(&e, DatasetError::NoDataset { dir, .. } if dir == d);
    let line = text(e);
    assert!(line.starts_with(&format!("{} holds no dataset nerf reads: ", d.display())));
    // A camera no lens has, in a capture: the camera's own error inside.
    let ns = d.join("ns");
    nerfstudio_capture(&ns, r#""fl_x": 1e-300, "fl_y": 50, "cx": 32, "cy": 24"#);
    let e = read_split(&ns, Split::Train).unwrap_err();
    assert_is!(
        &e,
        DatasetError::Camera {
            camera: CameraError::FieldOfView { axis: "x", .. },
            ..
        }
    );
    let line = format!(
        "{}: frame 0 (images/f0.png): nerfstudio camera_model OPENCV: a field of view of 180° \
         across x (64 px at focal length 1e-300 px) is not a lens's: it must be 0.5° to 179°",
        ns.join("transforms.json").display()
    );
    says(e, &line);
    // JSON that does not parse.
    std::fs::write(ns.join("transforms.json"), r#"{"frames": [1, 2"#).unwrap();
    let e = read_split(&ns, Split::Train).unwrap_err();
    assert_is!(e, DatasetError::Metadata { .. });
    let line = format!(
        "cannot parse {}: frames[0]: invalid type: integer `1`, expected struct FrameEntry at \
         line 1 column 13",
        ns.join("transforms.json").display()
    );
    says(e, &line);
    // A photo that does not decode, and one that is missing (f1, the train split's first).
    let photos = d.join("photos");
    nerfstudio_capture(&photos, r#""fl_x": 50, "fl_y": 50, "cx": 32, "cy": 24"#);
    assert_eq!(
        Dataset::load(&photos, Split::Train, 8, 6, false)
            .unwrap()
            .images
            .len(),
        7
    );
    let f1 = photos.join("images/f1.png");
    std::fs::write(&f1, b"not a png").unwrap();
    let e = Dataset::load(&photos, Split::Train, 8, 6, false).unwrap_err();
    assert_is!(&e, DatasetError::Photo { path, .. } if *path == f1);
    says(e, &format!("{} is not a PNG or JPEG image", f1.display()));
    std::fs::remove_file(&f1).unwrap();
    let e = Dataset::load(&photos, Split::Train, 8, 6, false).unwrap_err();
    assert_is!(&e, DatasetError::MissingFile { path, .. } if *path == f1);
    let line = format!(
        "cannot read image {}: No such file or directory (os error 2)",
        f1.display()
    );
    says(e, &line);
    // A COLMAP capture whose camera no lens has.
    let colmap = d.join("colmap");
    std::fs::create_dir_all(colmap.join("sparse/0")).unwrap();
    std::fs::create_dir_all(colmap.join("images")).unwrap();
    std::fs::write(
        colmap.join("sparse/0/cameras.txt"),
        "1 PINHOLE 64 48 1e-300 50 32 24\n",
    )
    .unwrap();
    std::fs::write(
        colmap.join("sparse/0/images.txt"),
        "1 1 0 0 0 0 0 3 1 a.png\n\n2 1 0 0 0 1 0 3 1 b.png\n\n",
    )
    .unwrap();
    let e = read_split(&colmap, Split::Train).unwrap_err();
    assert_is!(
        &e,
        DatasetError::Camera {
            camera: CameraError::FieldOfView { .. },
            ..
        }
    );
    let line = format!(
        "{}: camera 1 (of image a.png): COLMAP camera model PINHOLE: a field of view of 180° \
         across x (64 px at focal length 1e-300 px) is not a lens's: it must be 0.5° to 179°",
        colmap.join("sparse/0/cameras.txt").display()
    );
    says(e, &line);
}

#[test]
fn the_binary_prints_typed_errors_as_the_one_line_it_printed() {
    let o = common::nerf(&["render", "--config", "/nonexistent.yaml"]);
    assert!(!o.status.success());
    assert_eq!(
        common::stderr(&o).trim_end(),
        "error: config file /nonexistent.yaml not found"
    );
    let (dir, bad) = common::scratch("bad.safetensors");
    std::fs::write(&bad, b"hello world, not a checkpoint").unwrap();
    let o = common::nerf(&[
        "render",
        "--config",
        "nerf_lego_render",
        "--checkpoint",
        bad.to_str().unwrap(),
        "--out-dir",
        dir.path().to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let line = format!(
        "error: checkpoint {} is corrupt or not a checkpoint (neither safetensors nor a PyTorch \
         file)",
        bad.display()
    );
    assert_eq!(common::stderr(&o).trim_end(), line);
}
