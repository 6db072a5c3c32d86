//! Hostile inputs to the config, dataset and camera-path readers: YAML nested 100 000 deep,
//! oversized files, FIFOs where files belong, malformed overrides, cameras 1e300 away and
//! images wider than the decoder accepts. Each is refused quickly with one line.

mod common;

use nerf::config::yaml_bounds::MAX_YAML_BYTES;
use nerf::config::Config;
use nerf::io::camera_path::read_camera_path;
use nerf::io::dataset::{load_image, read_split, Split, MAX_SOURCE_IMAGE_SIDE};

#[test]
fn a_bad_override_names_itself_once_on_one_line() {
    for (o, what) in [
        ("x", "not of the form"),
        ("=1", "empty key"),
        ("a..b=1", "empty key"),
        ("sampler.n_pts_per_ray=[1", "cannot parse"),
        ("sampler.n_pts_per_ray.x=1", "is not a section"),
        ("a=\n[\n", "cannot parse"),
        ("sampler.n_pts_per_ray='x\ny'", "expected a whole number"),
    ] {
        let err = format!("{:#}", Config::load("box", &[o.to_string()]).unwrap_err());
        assert_eq!(err.matches("override").count(), 1, "{err}");
        assert!(err.contains(what) && !err.contains('\n'), "{err}");
    }
}

#[test]
fn deep_or_large_yaml_is_refused_quickly() {
    let start = std::time::Instant::now();
    let deep = format!("data: {}", "[".repeat(100_000));
    let err = format!("{:#}", Config::from_yaml(&deep, &[]).unwrap_err());
    assert!(err.contains("deeper than 64"), "{err}");
    let o = format!("data.image_size={}", "{a: ".repeat(100_000));
    let err = format!(
        "{:#}",
        Config::load("box", std::slice::from_ref(&o)).unwrap_err()
    );
    assert!(err.contains("deeper than 64") && err.len() < 200, "{err}");
    let o = format!("{}=1", vec!["a"; 100_000].join("."));
    let err = format!(
        "{:#}",
        Config::load("box", std::slice::from_ref(&o)).unwrap_err()
    );
    assert!(err.contains("more than 64 parts"), "{err}");
    assert!(start.elapsed() < std::time::Duration::from_secs(1));
    let (dir, big) = common::scratch("big.yaml");
    std::fs::write(&big, "# ".repeat(MAX_YAML_BYTES)).unwrap();
    let err = format!(
        "{:#}",
        Config::load(big.to_str().unwrap(), &[]).unwrap_err()
    );
    assert!(err.contains("more than"), "{err}");
    let fifo = dir.path().join("fifo.yaml");
    common::make_fifo(&fifo);
    let err = format!(
        "{:#}",
        Config::load(fifo.to_str().unwrap(), &[]).unwrap_err()
    );
    assert!(err.contains("FIFO"), "{err}");
}

#[test]
fn far_cameras_fifos_and_huge_images_are_refused_with_one_line() {
    let (dir, path) = common::scratch("transforms_train.json");
    let with_z = |z: &str| {
        format!(
            r#"{{"camera_angle_x": 0.69, "frames": [{{"file_path": "./train/r_0"}},
            {{"file_path": "./train/r_3", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, {z}], [0, 0, 0, 1]]}}]}}"#
        )
        .replace(r#"{"file_path": "./train/r_0"}"#, r#"{"file_path": "./train/r_0", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}"#)
    };
    for (z, ok) in [
        ("4", true),
        ("9999", true),
        ("1e300", false),
        ("-2e4", false),
    ] {
        std::fs::write(&path, with_z(z)).unwrap();
        match read_split(dir.path(), Split::Train) {
            Ok(frames) => assert!(ok && frames.len() == 2, "{z}"),
            Err(e) => {
                let e = e.to_string();
                assert!(
                    !ok && e.contains("frame 1 (./train/r_3)") && e.contains("farther"),
                    "{e}"
                );
                assert!(!e.contains('\n'));
            }
        }
    }
    // A FIFO in place of the transforms file is refused without blocking.
    std::fs::remove_file(&path).unwrap();
    common::make_fifo(&path);
    let start = std::time::Instant::now();
    let err = read_split(dir.path(), Split::Train)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("FIFO") && start.elapsed().as_secs() < 1,
        "{err}"
    );
    // So is one in place of an image.
    let err = load_image(&path, 8, 8, false).unwrap_err().to_string();
    assert!(err.contains("FIFO"), "{err}");
    // And one in place of a camera path.
    let err = read_camera_path(&path).unwrap_err().to_string();
    assert!(err.contains("FIFO") && err.contains("camera path"), "{err}");
    // An image wider than the decoder accepts is refused before it is decoded.
    let wide = dir.path().join("wide.png");
    image::GrayImage::new(MAX_SOURCE_IMAGE_SIDE + 1, 1)
        .save(&wide)
        .unwrap();
    let err = load_image(&wide, 8, 8, false).unwrap_err().to_string();
    assert!(err.contains("wide.png") && !err.contains('\n'), "{err}");
}
