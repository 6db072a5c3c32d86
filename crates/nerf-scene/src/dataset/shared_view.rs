//! Whether a capture's cameras share a view: a NeRF learns a point only from photos that see
//! it from more than one place, so cameras that each look at a different part of the world
//! (an outward-facing ring, a rig of cameras back to back) give nothing to train.
//!
//! **The rule** (`shared_view`): the scene is taken to lie within the ball around the
//! cameras (centred on the mean of their centres, reaching the farthest one: every capture
//! nerf reads looks into it, an object walked around, a facade photographed from a few steps
//! apart). Two cameras share a view when some point of that ball in front of one, on a ray
//! through its image, images inside the other's picture; the capture is refused when no pair
//! does. Rays are tried through a 5 × 5 grid of each image (corners and centre included) at
//! 16 depths to where they leave the ball. An inward ring sees the centre from every camera,
//! a forward-facing row sees in front of it from neighbouring cameras within a step's depth;
//! a camera of an outward-facing ring on the ball's rim looks out of the ball at once, so no
//! other camera sees what it sees inside it.

use glam::DVec3;

use nerf_core::camera::ColmapCamera;

/// Rays per image side.
const GRID: usize = 5;

/// Depths tried along each ray.
const DEPTHS: usize = 16;

/// Most cameras compared (evenly spaced when there are more): sharing a view is decided
/// among them.
const MAX_CAMERAS: usize = 256;

/// `Ok` when two of `cameras` share a view (see the module documentation); else why not, as
/// a phrase for a one-line error. Fewer than two cameras are not judged (`Ok`).
pub(crate) fn shared_view(cameras: &[ColmapCamera]) -> Result<(), String> {
    let step = cameras.len().div_ceil(MAX_CAMERAS).max(1);
    let cameras: Vec<&ColmapCamera> = cameras.iter().step_by(step).collect();
    if cameras.len() < 2 {
        // Nothing to compare: other checks speak of too few photos.
        return Ok(());
    }
    let centres: Vec<DVec3> = cameras.iter().map(|c| c.pose.center()).collect();
    let middle = centres.iter().copied().sum::<DVec3>() / centres.len() as f64;
    let radius = centres
        .iter()
        .map(|c| (*c - middle).length())
        .fold(0.0, f64::max);
    if !(radius.is_finite() && radius > 0.0) {
        return Err("the cameras all stand at one point".to_string());
    }
    let shares = |i: usize| {
        let camera = cameras[i];
        let (w, h) = (camera.size.0 as f64, camera.size.1 as f64);
        (0..GRID * GRID).any(|g| {
            let u = w * (g % GRID) as f64 / (GRID - 1) as f64;
            let v = h * (g / GRID) as f64 / (GRID - 1) as f64;
            let (origin, direction) = camera.ray_through_pixel(u, v);
            let Some(exit) = ball_exit(origin, direction, middle, radius) else {
                return false;
            };
            (0..DEPTHS).any(|k| {
                let point = origin + direction * exit * (k as f64 + 0.5) / DEPTHS as f64;
                cameras
                    .iter()
                    .enumerate()
                    .any(|(j, other)| j != i && images_inside(other, point))
            })
        })
    };
    if (0..cameras.len()).any(shares) {
        Ok(())
    } else {
        Err(format!(
            "no two of its {} cameras see a common part of the scene (what each sees within \
             {} of the cameras' centre is in no other's picture: cameras looking away from \
             each other, as an outward-facing ring)",
            cameras.len(),
            nerf_core::term::short_number(radius)
        ))
    }
}

/// The distance along the unit `direction` from `origin` (inside the ball) to where the ray
/// leaves the ball of `radius` around `centre`; `None` when there is no such positive
/// distance.
fn ball_exit(origin: DVec3, direction: DVec3, centre: DVec3, radius: f64) -> Option<f64> {
    let offset = origin - centre;
    let b = offset.dot(direction);
    let c = offset.length_squared() - radius * radius;
    let exit = -b + (b * b - c).max(0.0).sqrt();
    (exit.is_finite() && exit > 1e-9 * radius).then_some(exit)
}

/// An error naming the capture in `dir` unless the cameras of its `frames` share a view
/// (`shared_view`); frames of a NeRF-synthetic scene are not captures and pass.
pub fn check_capture_shares_a_view(
    dir: &std::path::Path,
    frames: &[super::Frame],
) -> anyhow::Result<()> {
    let cameras: Vec<ColmapCamera> = frames
        .iter()
        .filter_map(|f| match &f.camera {
            nerf_core::camera::Camera::Colmap(c) => Some(c.clone()),
            _ => None,
        })
        .collect();
    if cameras.len() < frames.len() {
        return Ok(());
    }
    shared_view(&cameras).map_err(|why| {
        anyhow::anyhow!(
            "{}: {why}; a NeRF learns only what two photos see, so there is nothing to train \
             on",
            dir.display()
        )
    })
}

/// Whether `camera` images `point` inside its picture (in front of it).
fn images_inside(camera: &ColmapCamera, point: DVec3) -> bool {
    let (w, h) = (camera.size.0 as f64, camera.size.1 as f64);
    camera
        .project(point)
        .is_some_and(|(u, v)| (0.0..=w).contains(&u) && (0.0..=h).contains(&v))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;
    use nerf_core::camera::ColmapPose;
    use std::path::Path;

    /// A 640×480 pinhole of about 60° across at `eye` looking along `forward`, up `up`.
    fn camera(eye: DVec3, forward: DVec3, up: DVec3) -> ColmapCamera {
        let z = forward.normalize();
        let x = z.cross(-up).normalize();
        let y = z.cross(x);
        let rotation = DMat3::from_cols(x, y, z).transpose();
        let pose = ColmapPose {
            rotation,
            translation: -(rotation * eye),
        };
        let params = [554.0, 554.0, 320.0, 240.0];
        ColmapCamera::from_colmap("PINHOLE", &params, (640, 480), pose).unwrap()
    }

    fn ring(n: usize, outward: bool) -> Vec<ColmapCamera> {
        (0..n)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / n as f64;
                let eye = DVec3::new(a.cos(), a.sin(), 0.0) * 3.0;
                let forward = if outward { eye } else { -eye };
                camera(eye, forward, DVec3::Z)
            })
            .collect()
    }

    #[test]
    fn an_inward_ring_and_a_forward_facing_row_share_a_view_an_outward_ring_does_not() {
        assert_eq!(shared_view(&ring(8, false)), Ok(()));
        assert_eq!(shared_view(&ring(3, false)), Ok(()));
        let row: Vec<_> = (0..6)
            .map(|i| camera(DVec3::new(i as f64 * 0.2, 0.0, 0.0), DVec3::Z, DVec3::Y))
            .collect();
        assert_eq!(shared_view(&row), Ok(()));
        // A grid of forward-facing cameras, slightly turned each way, as LLFF captures are.
        let grid: Vec<_> = (0..20)
            .map(|i| {
                let eye = DVec3::new((i % 5) as f64, (i / 5) as f64, 0.0) * 0.1;
                let turn = DVec3::new(((i * 7) % 5) as f64 - 2.0, 0.0, 0.0) * 0.02;
                camera(eye, DVec3::Z + turn, DVec3::Y)
            })
            .collect();
        assert_eq!(shared_view(&grid), Ok(()));
        // Outward rings, sparse and dense (their neighbours' pictures overlap only outside
        // the cameras' ball): refused, saying why.
        for n in [4, 8, 47, 300] {
            let err = shared_view(&ring(n, true)).unwrap_err();
            assert!(
                err.contains("no two of its") && !err.contains('\n'),
                "{err}"
            );
        }
        assert_eq!(shared_view(&ring(1, false)), Ok(()));
    }

    /// The cameras of the real captures and lego, when they are on this machine.
    #[test]
    fn the_real_captures_and_lego_share_a_view() {
        let real = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real");
        let mut checked = 0;
        if let Some(cameras) = temple_ring(&real.join("temple_ring/templeR_par.txt")) {
            assert_eq!(shared_view(&cameras), Ok(()), "temple_ring");
            checked += 1;
        }
        if let Some(cameras) = herzjesu(&real.join("herzjesu_p25/gt_dense_cameras")) {
            assert_eq!(shared_view(&cameras), Ok(()), "herzjesu_p25");
            checked += 1;
        }
        let bird = real.join("bird_handheld");
        if bird.join("sparse").is_dir() {
            let read = super::super::read_capture_split(
                &bird,
                super::super::llff::LLFF,
                super::super::Split::Train,
            )
            .unwrap();
            let cameras: Vec<_> = read
                .frames
                .iter()
                .filter_map(|f| match &f.camera {
                    nerf_core::camera::Camera::Colmap(c) => Some(c.clone()),
                    _ => None,
                })
                .collect();
            assert_eq!(shared_view(&cameras), Ok(()), "bird_handheld");
            checked += 1;
        }
        if let Some(lego) = super::super::test_lego_dir() {
            let text = std::fs::read_to_string(lego.join("transforms_train.json")).unwrap();
            let json: serde_json::Value = serde_json::from_str(&text).unwrap();
            let fov = json["camera_angle_x"].as_f64().unwrap();
            let focal = 400.0 / (fov / 2.0).tan();
            let cameras: Vec<_> = json["frames"]
                .as_array()
                .unwrap()
                .iter()
                .map(|f| {
                    let m = &f["transform_matrix"];
                    let c2w =
                        std::array::from_fn(|r| std::array::from_fn(|c| m[r][c].as_f64().unwrap()));
                    let float32 = ColmapPose::from_opengl_camera_to_world(c2w);
                    let rows = float32.rotation.transpose().to_cols_array_2d();
                    let pose = proper_pose(rows, float32.center());
                    let params = [focal, focal, 400.0, 400.0];
                    ColmapCamera::from_colmap("PINHOLE", &params, (800, 800), pose).unwrap()
                })
                .collect();
            assert_eq!(shared_view(&cameras), Ok(()), "lego");
            checked += 1;
        }
        eprintln!("{checked} of 4 captures checked (the others are not on this machine)");
    }

    /// temple_ring's `name k11..k33 r11..r33 t1 t2 t3` lines (world → camera, OpenCV axes).
    fn temple_ring(path: &Path) -> Option<Vec<ColmapCamera>> {
        let text = std::fs::read_to_string(path).ok()?;
        let cameras = text
            .lines()
            .skip(1)
            .filter_map(|line| {
                let v: Vec<f64> = line
                    .split_whitespace()
                    .skip(1)
                    .map(|x| x.parse().unwrap())
                    .collect();
                (v.len() == 21).then(|| {
                    let rotation = [0, 1, 2].map(|r| [v[9 + 3 * r], v[10 + 3 * r], v[11 + 3 * r]]);
                    let printed = ColmapPose::from_matrix(rotation, [v[18], v[19], v[20]]);
                    let pose = proper_pose(rotation, printed.center());
                    let params = [v[0], v[4], v[2], v[5]];
                    ColmapCamera::from_colmap("PINHOLE", &params, (640, 480), pose).unwrap()
                })
            })
            .collect();
        Some(cameras)
    }

    /// The pose of the world → camera `rotation` (row by row, printed to a few digits:
    /// snapped to the nearest rotation) with its camera at `centre`.
    fn proper_pose(rotation: [[f64; 3]; 3], centre: DVec3) -> ColmapPose {
        let printed = DMat3::from_cols_array_2d(&rotation).transpose();
        let rotation = DMat3::from_quat(glam::DQuat::from_mat3(&printed).normalize());
        ColmapPose {
            rotation,
            translation: -(rotation * centre),
        }
    }

    /// herzjesu_p25's `.camera` files: K (full size), distortion, R (camera → world), C, size.
    fn herzjesu(dir: &Path) -> Option<Vec<ColmapCamera>> {
        let mut files: Vec<_> = std::fs::read_dir(dir)
            .ok()?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        files.sort();
        let cameras = files
            .iter()
            .map(|file| {
                let text = std::fs::read_to_string(file).unwrap();
                let v: Vec<f64> = text
                    .split_whitespace()
                    .map(|x| x.parse().unwrap())
                    .collect();
                let k = |r: usize, c: usize| v[3 * r + c];
                let r = |row: usize, col: usize| v[12 + 3 * row + col];
                let centre = DVec3::new(v[21], v[22], v[23]);
                // World → camera: Rᵀ, −Rᵀ C.
                let rotation = [0, 1, 2].map(|row| [0, 1, 2].map(|col| r(col, row)));
                let pose = proper_pose(rotation, centre);
                let size = (v[24] as usize, v[25] as usize);
                let params = [k(0, 0), k(1, 1), k(0, 2), k(1, 2)];
                ColmapCamera::from_colmap("PINHOLE", &params, size, pose).unwrap()
            })
            .collect();
        Some(cameras)
    }
}
