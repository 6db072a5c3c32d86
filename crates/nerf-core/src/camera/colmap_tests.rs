//! Tests of `core::camera::colmap`: COLMAP's camera models, poses and nerfstudio's keys.

use super::*;
use crate::lens::colmap_camera_models;
use rand::{rngs::StdRng, Rng, SeedableRng};

const SIZE: (usize, usize) = (640, 480);

/// An arbitrary pose: a generic rotation and an off-axis translation.
fn arbitrary_pose() -> ColmapPose {
    ColmapPose::from_quaternion([0.9, 0.1, -0.3, 0.2], [0.3, -1.2, 2.5]).unwrap()
}

/// One camera of every model with realistic, non-zero distortion.
fn cameras_of_every_model() -> Vec<(&'static ColmapCameraModel, ColmapCamera)> {
    let params = |model: &ColmapCameraModel| -> Vec<f64> {
        match model.name {
            "SIMPLE_PINHOLE" => vec![500.0, 320.0, 240.0],
            "PINHOLE" => vec![510.0, 490.0, 322.5, 238.0],
            "SIMPLE_RADIAL" => vec![500.0, 320.0, 240.0, -0.08],
            "RADIAL" => vec![500.0, 320.0, 240.0, -0.1, 0.02],
            "OPENCV" => vec![510.0, 490.0, 322.5, 238.0, -0.1, 0.02, 1e-3, -5e-4],
            "FULL_OPENCV" => vec![
                510.0, 490.0, 322.5, 238.0, -0.1, 0.02, 1e-3, -5e-4, 0.003, 0.01, -0.005, 0.001,
            ],
            "OPENCV_FISHEYE" => vec![300.0, 302.0, 320.0, 240.0, 0.05, -0.01, 0.002, -5e-4],
            // Any other model: plausible values by parameter name.
            _ => model
                .parameters
                .iter()
                .map(|name| match *name {
                    "f" => 500.0,
                    "fx" => 510.0,
                    "fy" => 490.0,
                    "cx" => 322.5,
                    "cy" => 238.0,
                    "omega" => 0.9,
                    _ => 0.01,
                })
                .collect(),
        }
    };
    colmap_camera_models()
        .into_iter()
        .map(|model| {
            let camera = ColmapCamera::from_colmap(model.name, &params(model), SIZE, arbitrary_pose()).unwrap();
            (model, camera)
        })
        .collect()
}

/// Distance from `point` to the ray, relative to the point's distance from the origin.
fn relative_miss((origin, direction): (DVec3, DVec3), point: DVec3) -> f64 {
    let to_point = point - origin;
    to_point.cross(direction).length() / to_point.length()
}

#[test]
fn rays_through_projected_pixels_pass_through_the_points() {
    let mut rng = StdRng::seed_from_u64(22);
    for (model, camera) in cameras_of_every_model() {
        let mut worst: f64 = 0.0;
        let mut inside = 0;
        for _ in 0..500 {
            // A point in front of the camera, within about ±35° of the axis.
            let z = rng.random_range(0.3..20.0);
            let camera_point = DVec3::new(
                rng.random_range(-0.7..0.7) * z,
                rng.random_range(-0.5..0.5) * z,
                z,
            );
            let world_point = camera.pose.camera_to_world(camera_point);
            let (u, v) = camera.project(world_point).unwrap();
            if (0.0..640.0).contains(&u) && (0.0..480.0).contains(&v) {
                inside += 1;
            }
            let miss = relative_miss(camera.ray_through_pixel(u, v), world_point);
            worst = worst.max(miss);
        }
        eprintln!(
            "{}: worst relative ray miss {worst:.3e} ({inside}/500 inside the image)",
            model.name
        );
        assert!(inside > 300, "{}: points should mostly image", model.name);
        assert!(worst < 1e-5, "{}: {worst}", model.name);
    }
}

#[test]
fn pixel_ray_is_the_pixel_centre_and_scales_for_downscaled_images() {
    for (model, camera) in cameras_of_every_model() {
        for (i, j) in [(0, 0), (17, 300), (639, 479)] {
            let (o, d) = camera.pixel_ray(i, j, SIZE);
            let (o2, d2) = camera.ray_through_pixel(i as f64 + 0.5, j as f64 + 0.5);
            assert_eq!((o, d), (o2, d2), "{}", model.name);
        }
        // Half size: pixel (i, j) covers own pixels 2i..2i+2, centred at 2i + 1.
        let (_, d) = camera.pixel_ray(100, 50, (320, 240));
        let (_, d2) = camera.ray_through_pixel(201.0, 101.0);
        assert!((d - d2).length() < 1e-12, "{}", model.name);
    }
}

#[test]
fn pinhole_ray_matches_a_hand_computation() {
    let identity = ColmapPose::from_matrix(
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0; 3],
    );
    let camera =
        ColmapCamera::from_colmap("PINHOLE", &[500.0, 400.0, 320.0, 240.0], SIZE, identity)
            .unwrap();
    // Pixel (10, 20): centre (10.5, 20.5); x = (10.5 − 320) / 500 = −0.619,
    // y = (20.5 − 240) / 400 = −0.54875, z = 1 (up and left of the axis: y down).
    let (origin, direction) = camera.pixel_ray(10, 20, SIZE);
    let expected = DVec3::new(-0.619, -0.54875, 1.0).normalize();
    assert_eq!(origin, DVec3::ZERO);
    assert!((direction - expected).length() < 1e-15, "{direction}");
    // And it projects back to the pixel centre.
    let (u, v) = camera.project(direction * 3.0).unwrap();
    assert!((u - 10.5).abs() < 1e-12 && (v - 20.5).abs() < 1e-12);
}

#[test]
fn quaternion_and_matrix_poses_agree() {
    let pose = arbitrary_pose();
    let rows = pose.rotation.transpose().to_cols_array_2d();
    let again = ColmapPose::from_matrix(rows, pose.translation.to_array());
    assert!((again.rotation - pose.rotation).abs_diff_eq(DMat3::ZERO, 1e-15));
    // A half turn about x, camera at (0, 0, 5) looking down world −z.
    let half_turn = ColmapPose::from_quaternion([0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 5.0]).unwrap();
    assert!((half_turn.center() - DVec3::new(0.0, 0.0, 5.0)).length() < 1e-15);
    let forward = half_turn.rotation.transpose() * DVec3::Z;
    assert!((forward - DVec3::NEG_Z).length() < 1e-15);
}

fn nerfstudio_intrinsics(camera_model: &str) -> NerfstudioIntrinsics {
    NerfstudioIntrinsics {
        camera_model: camera_model.to_string(),
        fl_x: 510.0,
        fl_y: 490.0,
        cx: 322.5,
        cy: 238.0,
        w: 640,
        h: 480,
        k: [-0.1, 0.02, 0.0, 0.0],
        p: [1e-3, -5e-4],
    }
}

/// nerfstudio's camera-to-world at (0, 0, 5) with the identity OpenGL rotation: it looks
/// down world −z with +y up.
const OPENGL_AT_Z5: [[f64; 4]; 3] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 5.0],
];

#[test]
fn nerfstudio_opengl_and_colmap_poses_give_the_same_rays() {
    // By hand: COLMAP's pose of [`OPENGL_AT_Z5`] is the half turn about x, t = (0, 0, 5).
    let opengl = OPENGL_AT_Z5;
    let colmap_pose = ColmapPose::from_quaternion([0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 5.0]).unwrap();
    let params = [510.0, 490.0, 322.5, 238.0, -0.1, 0.02, 1e-3, -5e-4];
    let pairs = [
        (
            ColmapCamera::from_nerfstudio(opengl, &nerfstudio_intrinsics("OPENCV")).unwrap(),
            ColmapCamera::from_colmap("OPENCV", &params, SIZE, colmap_pose).unwrap(),
        ),
        {
            // The arbitrary pose written as nerfstudio would: c2w with y, z negated.
            let pose = arbitrary_pose();
            let c2w_cv = pose.rotation.transpose();
            let c = pose.center();
            let cols = [c2w_cv.x_axis, -c2w_cv.y_axis, -c2w_cv.z_axis, c];
            let opengl = [0, 1, 2].map(|i| cols.map(|col| col[i]));
            (
                ColmapCamera::from_nerfstudio(opengl, &nerfstudio_intrinsics("OPENCV")).unwrap(),
                ColmapCamera::from_colmap("OPENCV", &params, SIZE, pose).unwrap(),
            )
        },
    ];
    for (nerfstudio, colmap) in pairs {
        for (i, j) in [(0, 0), (320, 240), (5, 470), (600, 33)] {
            let (o1, d1) = nerfstudio.pixel_ray(i, j, SIZE);
            let (o2, d2) = colmap.pixel_ray(i, j, SIZE);
            assert!((o1 - o2).length() < 1e-12 && (d1 - d2).length() < 1e-12);
        }
    }
    // The principal point looks straight ahead: world −z for the first pair.
    let camera = ColmapCamera::from_nerfstudio(opengl, &nerfstudio_intrinsics("OPENCV")).unwrap();
    assert!((camera.direction_at_pixel(322.5, 238.0) - DVec3::NEG_Z).length() < 1e-15);
    // Image up (smaller v) is world +y.
    assert!(camera.direction_at_pixel(322.5, 0.0).y > 0.0);
}

#[test]
fn a_nearly_orthonormal_float32_rotation_keeps_the_files_camera_centre() {
    // A rotation 1e-6 from orthonormal (the diagonal scaled), far from the origin.
    let centre = [30.0, -20.0, 50.0];
    let c2w = [0, 1, 2].map(|i| {
        let mut row = [0.0; 4];
        row[i] = 1.0 + 1e-6;
        row[3] = centre[i];
        row
    });
    let camera = ColmapCamera::from_nerfstudio(c2w, &nerfstudio_intrinsics("OPENCV")).unwrap();
    let moved = (camera.pose.center() - DVec3::from_array(centre)).length();
    // RᵀR c would be 2e-6 · |c| ≈ 1.2e-4 away.
    assert!(moved < 1e-12, "{moved}");
}

#[test]
fn nerfstudio_fisheye_and_k3_k4_are_supported() {
    let c2w = OPENGL_AT_Z5;
    let mut opencv = nerfstudio_intrinsics("OPENCV");
    opencv.k = [-0.12, 0.03, -0.004, 0.0005];
    let mut fisheye = nerfstudio_intrinsics("OPENCV_FISHEYE");
    fisheye.k = [0.05, -0.01, 0.002, -5e-4];
    assert!(ColmapCamera::from_nerfstudio(c2w, &fisheye).is_err()); // p1, p2 set
    fisheye.p = [0.0, 0.0];
    for intrinsics in [opencv, fisheye] {
        let camera = ColmapCamera::from_nerfstudio(c2w, &intrinsics).unwrap();
        let point = DVec3::new(1.2, -0.7, -2.0);
        let (u, v) = camera.project(point).unwrap();
        let miss = relative_miss(camera.ray_through_pixel(u, v), point);
        assert!(miss < 1e-10, "{}: {miss}", intrinsics.camera_model);
    }
    let error = ColmapCamera::from_nerfstudio(c2w, &nerfstudio_intrinsics("EQUIRECTANGULAR"))
        .unwrap_err()
        .to_string();
    assert!(error.contains("EQUIRECTANGULAR") && error.contains("OPENCV_FISHEYE"));
}

#[test]
fn wrong_parameter_counts_and_unknown_models_are_errors_naming_the_model() {
    let pose = arbitrary_pose();
    for model in colmap_camera_models() {
        let n = model.parameters.len();
        let error = ColmapCamera::from_colmap(model.name, &vec![1.0; n + 1], SIZE, pose)
            .unwrap_err()
            .to_string();
        assert!(error.contains(model.name), "{error}");
        assert!(error.contains(&format!("takes {n} parameters")), "{error}");
    }
    let error = ColmapCamera::from_colmap("OPENCV", &[500.0, 320.0, 240.0], SIZE, pose)
        .unwrap_err()
        .to_string();
    assert_eq!(
        error,
        "COLMAP camera model OPENCV takes 8 parameters \
         (fx, fy, cx, cy, k1, k2, p1, p2), got 3"
    );
    let error = ColmapCamera::from_colmap("THIN_PRISM_FISHEYE", &[1.0; 12], SIZE, pose)
        .unwrap_err()
        .to_string();
    assert!(error.contains("THIN_PRISM_FISHEYE"), "{error}");
    assert!(error.contains("SIMPLE_PINHOLE, PINHOLE"), "{error}");
}

#[test]
fn validate_rejects_bad_focal_lengths_and_rotations() {
    let pose = arbitrary_pose();
    let error =
        ColmapCamera::from_colmap("SIMPLE_PINHOLE", &[-5.0, 1.0, 1.0], SIZE, pose).unwrap_err();
    assert!(format!("{error:#}").contains("focal lengths must be positive"));
    let sheared = ColmapPose::from_matrix(
        [[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0; 3],
    );
    let error =
        ColmapCamera::from_colmap("SIMPLE_PINHOLE", &[5.0, 1.0, 1.0], SIZE, sheared).unwrap_err();
    assert!(format!("{error:#}").contains("not a proper rotation"));
    let mirror = ColmapPose::from_matrix(
        [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0; 3],
    );
    assert!(ColmapCamera::from_colmap("SIMPLE_PINHOLE", &[5.0, 1.0, 1.0], SIZE, mirror).is_err());
    let nan = ColmapCamera::from_colmap("SIMPLE_RADIAL", &[5.0, 1.0, 1.0, f64::NAN], SIZE, pose);
    assert!(format!("{:#}", nan.unwrap_err()).contains("non-finite"));
    assert!(ColmapPose::from_quaternion([0.0; 4], [0.0; 3]).is_err());
}

#[test]
fn unproject_ndc_maps_the_homework_square_onto_the_image() {
    for (model, camera) in cameras_of_every_model() {
        for (x, y) in [(1.0, 1.0), (-1.0, -1.0), (0.3, -0.6), (0.0, 0.0)] {
            let point = camera.unproject_ndc(x, y, 2.5);
            // View depth 2.5 …
            let depth = camera.pose.world_to_camera(point).z;
            assert!((depth - 2.5).abs() < 1e-12, "{}", model.name);
            // … imaged at u = (1 − x)/2 · W, v = (1 − y)/2 · H.
            let (u, v) = camera.project(point).unwrap();
            let (eu, ev) = ((1.0 - x) / 2.0 * 640.0, (1.0 - y) / 2.0 * 480.0);
            assert!(
                (u - eu).abs() < 1e-8 && (v - ev).abs() < 1e-8,
                "{}",
                model.name
            );
            let (o, d) = camera.ray_through_ndc(x, y);
            assert!(relative_miss((o, d), point) < 1e-12);
        }
        assert_eq!(camera.center(), camera.pose.center());
    }
}

#[test]
fn points_behind_the_camera_do_not_project() {
    let (_, camera) = &cameras_of_every_model()[4];
    let behind = camera.pose.camera_to_world(DVec3::new(0.1, 0.2, -3.0));
    assert_eq!(camera.project(behind), None);
    assert_eq!(camera.project(DVec3::NAN), None);
}
