//! COLMAP sparse models: text and binary files read back what was written (bit for bit),
//! a model as COLMAP writes it is read, the model of a capture directory is found, huge
//! points files are bounded, and broken or hostile files are refused with one line naming
//! the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nerf::io::colmap::{
    find_model, find_model_with, read_model, write_binary, write_text, ColmapCameraRecord,
    ColmapFormat, ColmapImage, ColmapModel, ColmapPoint2D, ColmapPoint3D, ColmapReadOptions,
};

/// Reads everything: 2D features and every point.
const ALL: ColmapReadOptions = ColmapReadOptions {
    points2d: true,
    max_points3d: usize::MAX,
};

fn camera(id: u32, model: &str, params: &[f64]) -> ColmapCameraRecord {
    ColmapCameraRecord {
        id,
        model: model.to_string(),
        width: 640 + id as u64,
        height: 480,
        params: params.to_vec(),
    }
}

fn image(id: u32, camera_id: u32, name: &str, points2d: Vec<ColmapPoint2D>) -> ColmapImage {
    let a = id as f64 * 0.1;
    ColmapImage {
        id,
        qvec: [a.cos(), a.sin() / 3.0, -0.2, 1e-7],
        tvec: [
            -1.0 / 3.0,
            std::f64::consts::PI * id as f64,
            12345.678901234567,
        ],
        camera_id,
        name: name.to_string(),
        points2d,
    }
}

/// Several cameras of different models (FULL_OPENCV's 12 parameters, a fisheye), images in
/// subfolders (sorted by name, as read), with and without 2D features, and 3D points, with
/// numbers that print long.
fn sample_model(n_images: u32) -> ColmapModel {
    let cameras: BTreeMap<u32, ColmapCameraRecord> = [
        camera(1, "PINHOLE", &[500.0, 501.5, 320.0, 240.0]),
        camera(
            2,
            "OPENCV",
            &[600.1, 600.2, 319.5, 239.5, -0.1, 0.01, 1e-4, -2e-5],
        ),
        camera(
            3,
            "FULL_OPENCV",
            &[
                700.0,
                701.0,
                330.0,
                250.0,
                -0.3,
                0.1,
                1e-3,
                -1e-3,
                0.02,
                0.1 + 0.2,
                -1e-300,
                f64::MIN_POSITIVE,
            ],
        ),
        camera(
            7,
            "OPENCV_FISHEYE",
            &[400.0, 400.0, 320.0, 240.0, 0.1, -0.05, 0.01, -1e-3],
        ),
        camera(9, "SIMPLE_RADIAL", &[450.25, 320.0, 240.0, -0.0218531]),
    ]
    .into_iter()
    .map(|c| (c.id, c))
    .collect();
    let camera_ids = [1, 2, 3, 7, 9];
    let mut images: Vec<ColmapImage> = (0..n_images)
        .map(|i| {
            let features = if i % 2 == 0 {
                vec![
                    ColmapPoint2D {
                        xy: [10.5, 20.25],
                        point3d_id: Some(3),
                    },
                    ColmapPoint2D {
                        xy: [-0.1, 1e10],
                        point3d_id: None,
                    },
                    ColmapPoint2D {
                        xy: [639.999, 0.0],
                        point3d_id: Some(u64::MAX - 1),
                    },
                ]
            } else {
                Vec::new()
            };
            let name = format!("cam{}/sub dir/frame_{i:03}.png", i % 3);
            image(100 - i, camera_ids[i as usize % 5], &name, features)
        })
        .collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let points = (0..7)
        .map(|i| ColmapPoint3D {
            id: i * 5 + 1,
            xyz: [i as f64 / 7.0, -1e-9 * i as f64, 3e8],
            rgb: [i as u8 * 30, 255, 0],
            error: 0.5 / (i as f64 + 1.0),
        })
        .collect();
    ColmapModel {
        cameras,
        images,
        points,
    }
}

/// The error of `result` as one line, asserted to name `file` (and, for text files, `line`).
fn one_line_error<T: std::fmt::Debug>(result: anyhow::Result<T>, file: &Path) -> String {
    let e = result.unwrap_err().to_string();
    assert!(!e.contains('\n'), "more than one line: {e}");
    assert!(
        e.contains(&file.display().to_string()),
        "does not name {}: {e}",
        file.display()
    );
    e
}

/// Writes `model` into `dir` in `format`.
fn write_in(format: ColmapFormat, dir: &Path, model: &ColmapModel) {
    match format {
        ColmapFormat::Binary => write_binary(dir, model).unwrap(),
        ColmapFormat::Text => write_text(dir, model).unwrap(),
    }
}

/// A four-image sample model written in `format` into a fresh directory: the directory, the
/// model and its three files (cameras, images, points).
fn written_sample(format: ColmapFormat) -> (tempfile::TempDir, ColmapModel, [PathBuf; 3]) {
    let dir = tempfile::tempdir().unwrap();
    let model = sample_model(4);
    write_in(format, dir.path(), &model);
    let files = format.files(dir.path());
    (dir, model, files)
}

/// Writes `contents` over `file` of the model in `d`, reads the model and returns its one-line
/// error, which names `file`.
fn error_after_writing(d: &Path, file: &Path, contents: impl AsRef<[u8]>) -> String {
    std::fs::write(file, contents).unwrap();
    one_line_error(read_model(d, &ALL), file)
}

#[test]
fn text_and_binary_models_read_back_exactly_what_was_written() {
    let model = sample_model(7);
    let dir = tempfile::tempdir().unwrap();
    for format in [ColmapFormat::Binary, ColmapFormat::Text] {
        let out = dir.path().join(format.extension());
        write_in(format, &out, &model);
        for f in format.files(&out) {
            assert!(f.is_file(), "{} not written", f.display());
        }
        let back = read_model(&out, &ALL).unwrap();
        // Bit for bit: text numbers are written in the shortest form that reads back exactly.
        assert_eq!(back, model, "{format:?}");
        assert_eq!(back.camera_of(&back.images[0]).id, back.images[0].camera_id);
        // By default, no 2D features are kept; poses and points are.
        let poses = read_model(&out, &ColmapReadOptions::default()).unwrap();
        assert!(poses.images.iter().all(|i| i.points2d.is_empty()));
        assert_eq!(poses.points, model.points);
        let names: Vec<_> = poses.images.iter().map(|i| i.name.as_str()).collect();
        let originals: Vec<_> = model.images.iter().map(|i| i.name.as_str()).collect();
        assert_eq!(names, originals);
    }
    // Images come sorted by name whatever the order in the file.
    let mut reversed = model.clone();
    reversed.images.reverse();
    let out = dir.path().join("reversed");
    write_binary(&out, &reversed).unwrap();
    assert_eq!(read_model(&out, &ALL).unwrap(), model);
}

#[test]
fn a_text_model_as_colmap_writes_it_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("cameras.txt"),
        "# Camera list with one line of data per camera:\n\
         #   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n\
         # Number of cameras: 2\n\
         1 SIMPLE_PINHOLE 3072 2304 2559.81 1536 1152\n\
         \n\
         2 OPENCV_FISHEYE 1920 1080 800 801 960 540 0.1 0.01 -0.001 1e-4\n",
    )
    .unwrap();
    // The second image has no features: its second line is empty. Windows line ends.
    std::fs::write(
        d.join("images.txt"),
        "# Image list with two lines of data per image:\r\n\
         #   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\r\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)\r\n\
         # Number of images: 2, mean observations per image: 1.5\r\n\
         5 0.851773 0.0165051 0.503764 -0.142941 -0.737434 1.02973 3.74354 1 day1/P1180141.JPG\r\n\
         2362.39 248.498 58396 1784.7 268.254 -1 1784.7 268.254 7\r\n\
         3 1 0 0 0 0 0 0 2 day2/P1180142.JPG\r\n\
         \r\n",
    )
    .unwrap();
    std::fs::write(
        d.join("points3D.txt"),
        "# 3D point list with one line of data per point:\n\
         #   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n\
         # Number of points: 2, mean track length: 3.0\n\
         63390 1.67241 0.292931 0.609726 115 121 122 1.33927 16 6542 15 7345 6 6714 14 7227\n\
         7 -1 -2 -3 0 0 255 0.5\n",
    )
    .unwrap();
    let model = read_model(d, &ALL).unwrap();
    assert_eq!(model.cameras.len(), 2);
    assert_eq!(model.cameras[&1].params, vec![2559.81, 1536.0, 1152.0]);
    assert_eq!(model.cameras[&2].model, "OPENCV_FISHEYE");
    assert_eq!(
        (model.cameras[&2].width, model.cameras[&2].height),
        (1920, 1080)
    );
    let names: Vec<_> = model.images.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(names, ["day1/P1180141.JPG", "day2/P1180142.JPG"]);
    let first = &model.images[0];
    assert_eq!(first.id, 5);
    assert_eq!(first.qvec, [0.851773, 0.0165051, 0.503764, -0.142941]);
    assert_eq!(first.tvec, [-0.737434, 1.02973, 3.74354]);
    assert_eq!(
        first
            .points2d
            .iter()
            .map(|p| p.point3d_id)
            .collect::<Vec<_>>(),
        [Some(58396), None, Some(7)]
    );
    assert_eq!(first.points2d[0].xy, [2362.39, 248.498]);
    assert!(model.images[1].points2d.is_empty());
    assert_eq!(model.images[1].camera_id, 2);
    assert_eq!(
        model.points,
        [
            ColmapPoint3D {
                id: 63390,
                xyz: [1.67241, 0.292931, 0.609726],
                rgb: [115, 121, 122],
                error: 1.33927
            },
            ColmapPoint3D {
                id: 7,
                xyz: [-1.0, -2.0, -3.0],
                rgb: [0, 0, 255],
                error: 0.5
            }
        ]
    );
    // Without a points file the model has no points.
    std::fs::remove_file(d.join("points3D.txt")).unwrap();
    assert!(read_model(d, &ALL).unwrap().points.is_empty());
}

#[test]
fn find_model_takes_the_sparse_model_with_the_most_images_and_ignores_other_files() {
    let capture = tempfile::tempdir().unwrap();
    let c = capture.path();
    write_binary(&c.join("sparse/0"), &sample_model(2)).unwrap();
    write_text(&c.join("sparse/1"), &sample_model(4)).unwrap();
    write_binary(&c.join("sparse/2"), &sample_model(3)).unwrap();
    // Newer COLMAP's rigs and frames, and anything else, are not read.
    std::fs::write(c.join("sparse/1/rigs.bin"), b"not a rig file").unwrap();
    std::fs::write(c.join("sparse/1/frames.bin"), [0xffu8; 3]).unwrap();
    std::fs::write(c.join("sparse/1/project.ini"), "[General]\n").unwrap();
    std::fs::create_dir_all(c.join("images/cam0")).unwrap();
    let (dir, model) = find_model(c).unwrap();
    assert_eq!(dir, c.join("sparse/1"));
    assert_eq!(model.images.len(), 4);
    // Default options: poses and points, no 2D features.
    assert!(model.images.iter().all(|i| i.points2d.is_empty()));
    assert_eq!(model.points.len(), 7);
    // Given the sparse folder, or the model folder itself, the same.
    assert_eq!(find_model(&c.join("sparse")).unwrap().0, c.join("sparse/1"));
    let (dir, model) = find_model_with(&c.join("sparse/1"), &ALL).unwrap();
    assert_eq!((dir, model), (c.join("sparse/1"), sample_model(4)));
    // A model unreadable among readable ones is passed over.
    std::fs::write(c.join("sparse/1/images.txt"), "garbage\n").unwrap();
    assert_eq!(find_model(c).unwrap().0, c.join("sparse/2"));
}

#[test]
fn find_model_reads_sparse_directly_and_prefers_binary_files() {
    let capture = tempfile::tempdir().unwrap();
    let c = capture.path();
    // A model in sparse/ itself, nerfstudio's colmap/sparse/0 beside it: sparse/ comes first.
    write_text(&c.join("sparse"), &sample_model(3)).unwrap();
    write_binary(&c.join("colmap/sparse/0"), &sample_model(6)).unwrap();
    assert_eq!(find_model(c).unwrap().0, c.join("sparse"));
    // Binary and text side by side: binary is read.
    write_binary(&c.join("sparse"), &sample_model(5)).unwrap();
    let (_, model) = find_model(c).unwrap();
    assert_eq!(model.images.len(), 5);
    // nerfstudio's layout.
    std::fs::remove_dir_all(c.join("sparse")).unwrap();
    let (dir, model) = find_model(c).unwrap();
    assert_eq!((dir, model.images.len()), (c.join("colmap/sparse/0"), 6));
}

#[test]
fn no_model_names_the_places_looked() {
    let capture = tempfile::tempdir().unwrap();
    let c = capture.path();
    std::fs::create_dir_all(c.join("sparse/0")).unwrap();
    // Half a model is no model.
    std::fs::write(c.join("sparse/0/cameras.bin"), [0u8; 8]).unwrap();
    let e = one_line_error(find_model(c), c);
    assert!(
        e.contains("no COLMAP model") && e.contains("sparse") && e.contains("images.bin"),
        "{e}"
    );
    let e = one_line_error(find_model(&c.join("missing")), &c.join("missing"));
    assert!(e.contains("not a folder"), "{e}");
}

#[test]
fn broken_binary_files_are_refused_on_one_line_naming_the_file() {
    let (dir, model, [cameras, images, points]) = written_sample(ColmapFormat::Binary);
    let d = dir.path();
    let original = std::fs::read(&images).unwrap();

    // Truncated inside the last image's features.
    let e = error_after_writing(d, &images, &original[..original.len() - 5]);
    assert!(e.contains("truncated"), "{e}");
    // Cut inside a record (the last camera's last parameter).
    let original_cameras = std::fs::read(&cameras).unwrap();
    let e = error_after_writing(d, &cameras, &original_cameras[..original_cameras.len() - 4]);
    assert!(
        e.contains("truncated: a parameter of camera 9 needs 8 bytes, 4 are left"),
        "{e}"
    );
    std::fs::write(&cameras, &original_cameras).unwrap();
    // Bytes past the last record.
    let e = error_after_writing(d, &images, [&original[..], &[0u8; 3]].concat());
    assert!(e.contains("3 bytes after the last record"), "{e}");

    // A huge count is refused at once, before anything is allocated for it.
    for huge in [1u64 << 40, u64::MAX] {
        let mut bytes = original.clone();
        bytes[..8].copy_from_slice(&huge.to_le_bytes());
        std::fs::write(&images, &bytes).unwrap();
        let start = Instant::now();
        let e = one_line_error(read_model(d, &ALL), &images);
        assert!(start.elapsed() < Duration::from_secs(1));
        assert!(e.contains(&format!("counts {huge} images")), "{e}");
    }
    std::fs::write(&images, &original).unwrap();
    // A huge track length in the points file (the first point's, after 8 + 51 - 8 bytes).
    let original_points = std::fs::read(&points).unwrap();
    let mut bytes = original_points.clone();
    bytes[51..59].copy_from_slice(&(1u64 << 62).to_le_bytes());
    let e = error_after_writing(d, &points, &bytes);
    assert!(e.contains("track elements of 3D point 1"), "{e}");
    // ... which is not read at all when points are skipped.
    let no_points = ColmapReadOptions {
        points2d: false,
        max_points3d: 0,
    };
    assert_eq!(read_model(d, &no_points).unwrap().points.len(), 0);
    std::fs::write(&points, &original_points).unwrap();

    // NaN as the first parameter of the first camera (after the count, ids and size).
    let mut bytes = original_cameras.clone();
    bytes[32..40].copy_from_slice(&f64::NAN.to_le_bytes());
    let e = error_after_writing(d, &cameras, &bytes);
    assert!(e.contains("NaN") && e.contains("camera 1"), "{e}");
    // An unknown camera model id.
    let mut bytes = original_cameras.clone();
    bytes[12..16].copy_from_slice(&99i32.to_le_bytes());
    let e = error_after_writing(d, &cameras, &bytes);
    assert!(e.contains("model id 99"), "{e}");

    // An image whose camera is not in the cameras file.
    let mut fewer = model.clone();
    fewer.cameras.remove(&3);
    fewer.images.retain(|i| i.camera_id != 3);
    let other = tempfile::tempdir().unwrap();
    write_binary(other.path(), &fewer).unwrap();
    std::fs::copy(other.path().join("cameras.bin"), &cameras).unwrap();
    let e = one_line_error(read_model(d, &ALL), &images);
    assert!(
        e.contains("uses camera 3") && e.contains(&cameras.display().to_string()),
        "{e}"
    );

    // No images at all.
    let e = error_after_writing(d, &images, 0u64.to_le_bytes());
    assert!(e.contains("no images"), "{e}");
    // Not a regular file.
    std::fs::remove_file(&images).unwrap();
    std::fs::create_dir(&images).unwrap();
    let e = one_line_error(read_model(d, &ALL), &images);
    assert!(e.contains("a directory"), "{e}");
}

#[test]
fn broken_text_files_are_refused_on_one_line_naming_the_file_and_line() {
    let (dir, model, [cameras, images, points]) = written_sample(ColmapFormat::Text);
    let d = dir.path();
    let original = std::fs::read_to_string(&images).unwrap();
    let lines: Vec<&str> = original.lines().collect();
    // Line 5 is the first image's first line (after four comment lines).
    let with_line_5 = |new: &str| {
        let mut l = lines.clone();
        l[4] = new;
        l.join("\n") + "\n"
    };
    let fields: Vec<&str> = lines[4].split(' ').collect();

    for (bad, why) in [
        ("nan", "not a finite number"),
        ("inf", "not a finite number"),
    ] {
        let mut f = fields.clone();
        f[2] = bad;
        let e = error_after_writing(d, &images, with_line_5(&f.join(" ")));
        assert!(e.contains("line 5") && e.contains(why), "{e}");
    }
    let mut f = fields.clone();
    f[8] = "42";
    let e = error_after_writing(d, &images, with_line_5(&f.join(" ")));
    assert!(e.contains("uses camera 42"), "{e}");
    let mut f = fields.clone();
    f[9] = "../outside.png";
    let e = error_after_writing(d, &images, with_line_5(&f.join(" ")));
    assert!(
        e.contains("line 5") && e.contains("not a path inside"),
        "{e}"
    );
    // An image's feature line left out: the next image's first line is not taken for it.
    let mut l = lines.clone();
    l.remove(5);
    let e = error_after_writing(d, &images, l.join("\n") + "\n");
    assert!(e.contains("line 6") && e.contains("2D feature line"), "{e}");
    // Nothing but comments: no images.
    let e = error_after_writing(d, &images, "# Number of images: 0\n");
    assert!(e.contains("no images"), "{e}");
    std::fs::write(&images, &original).unwrap();

    let e = error_after_writing(d, &cameras, "1 PINHOLE 640 480 500 500 320\n");
    assert!(
        e.contains("line 1") && e.contains("3 parameters, not 4"),
        "{e}"
    );
    let e = error_after_writing(d, &cameras, "# c\n1 BROWN 640 480 500 500 320\n");
    assert!(e.contains("line 2") && e.contains("\"BROWN\""), "{e}");

    write_text(d, &model).unwrap();
    let e = error_after_writing(d, &points, "1 0 0 NaN 0 0 0 0.5\n");
    assert!(e.contains("line 1") && e.contains("z is NaN"), "{e}");
    let e = error_after_writing(d, &points, "1 0 0 0 0 256 0 0.5\n");
    assert!(e.contains("green"), "{e}");
}

#[test]
fn writing_refuses_a_model_that_could_not_be_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model");
    let mut model = sample_model(3);
    model.images[1].camera_id = 8;
    let e = one_line_error(write_text(&out, &model), &out.join("images.txt"));
    assert!(e.contains("uses camera 8"), "{e}");
    let mut model = sample_model(3);
    model.images[0].tvec[1] = f64::INFINITY;
    let e = one_line_error(write_binary(&out, &model), &out.join("images.bin"));
    assert!(e.contains("not a finite number"), "{e}");
    let mut model = sample_model(3);
    model.cameras.get_mut(&3).unwrap().params.pop();
    let e = one_line_error(write_binary(&out, &model), &out.join("cameras.bin"));
    assert!(e.contains("11 parameters, not 12"), "{e}");
    assert!(!out.join("images.bin").exists() && !out.join("images.txt").exists());
}

#[test]
fn points_are_bounded_and_spread_over_the_whole_file() {
    let dir = tempfile::tempdir().unwrap();
    let mut model = sample_model(2);
    model.points = (0..1000u64)
        .map(|i| ColmapPoint3D {
            id: i,
            xyz: [i as f64, 0.0, 0.0],
            rgb: [1, 2, 3],
            error: 0.25,
        })
        .collect();
    for format in [ColmapFormat::Binary, ColmapFormat::Text] {
        let out = dir.path().join(format.extension());
        write_in(format, &out, &model);
        let limited = ColmapReadOptions {
            points2d: false,
            max_points3d: 30,
        };
        let points = read_model(&out, &limited).unwrap().points;
        // Every 34th: ids 0, 34, ..., 986 (30 points), from the start to the end.
        let ids: Vec<u64> = points.iter().map(|p| p.id).collect();
        assert_eq!(
            ids,
            (0..30).map(|i| i * 34).collect::<Vec<_>>(),
            "{format:?}"
        );
        assert_eq!(points[1], model.points[34]);
        let all = read_model(&out, &ALL).unwrap();
        assert_eq!(all.points, model.points);
        let none = ColmapReadOptions {
            points2d: false,
            max_points3d: 0,
        };
        assert!(read_model(&out, &none).unwrap().points.is_empty());
    }
}
