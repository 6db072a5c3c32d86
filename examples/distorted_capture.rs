//! A COLMAP capture of the lego made from its NeRF-synthetic training views, as a camera with
//! lens distortion would have taken them, in an arbitrary world frame: the test fixture of
//! the "bring your own scene" criterion (docs/own-scene.md).
//!
//! Each of the 100 training renders (800×800, pinhole) is resampled into an `N × N` photo of
//! an OPENCV camera (`k1 k2 p1 p2` below) at the same pose: every output pixel's ray (through
//! the distortion model, [`ColmapCamera::ray_through_pixel`]) is projected into the render
//! and the render is read there bilinearly, 4×4 rays per output pixel averaged (colour
//! premultiplied by alpha, so no fringes), and written as RGBA like the renders, so that the
//! loader composites it on the config's background as it does the NeRF-synthetic images.
//! (Composited on white instead, `nerf_scene` must paint the white with density on a shell
//! around cameras that stand inside its box, and the held-out views score badly; measured:
//! docs/own-scene.md#white-backdrops.) With
//! `--pinhole` the same photos come from a pinhole camera
//! of the same focal length instead, the undistorted equivalent. The poses are moved into an
//! arbitrary similarity gauge (a rotation, a translation and a scale of the world, as
//! structure from motion leaves them) and written as a COLMAP model, `OUT/sparse/0/` (text,
//! or binary with `--binary`), with the photos in `OUT/images/r_NNN.png`.
//!
//! With `--white` the photos are composited on white and written as JPEGs without alpha
//! (`r_NNN.jpg`, quality 95), as a camera photographing the object on a white backdrop would
//! take them: the fixture of the white-backdrop criterion of nerf_scene (docs/own-scene.md).
//!
//! Run: `cargo run --release --example distorted_capture -- LEGO_DIR OUT [--size N]
//! [--pinhole] [--binary] [--white]` (LEGO_DIR: the NeRF-synthetic lego, `../shared/data/lego`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use glam::{DMat3, DQuat, DVec3};
use nerf::core::camera::{ColmapCamera, ColmapPose};
use nerf::io::colmap::{self, ColmapImage, ColmapModel};

/// OPENCV distortion `k1 k2 p1 p2`: a moderate barrel distortion with a little tangential
/// part, as a phone or action camera's lens has.
const DISTORTION: [f64; 4] = [-0.12, 0.03, 0.001, -0.0015];

/// The photos' focal length over the renders' (scaled to the photo size): a little longer, so
/// that every distorted ray, corners included, falls inside the render.
const FOCAL_SCALE: f64 = 1.06;

/// Rays per output pixel along each axis.
const SUPERSAMPLE: usize = 4;

/// A training render: RGBA in [0, 1], row-major, and its camera → world (OpenGL axes).
struct Render {
    size: (usize, usize),
    rgba: Vec<[f32; 4]>,
    c2w: [[f64; 4]; 4],
}

impl Render {
    /// Bilinear premultiplied RGBA (`[r·a, g·a, b·a, a]`) at pixel position `(u, v)`
    /// (COLMAP's convention, centres at i + 0.5); `None` outside the image.
    fn sample(&self, u: f64, v: f64) -> Option<[f32; 4]> {
        let (w, h) = self.size;
        let (x, y) = (u - 0.5, v - 0.5);
        if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let premultiplied = |x: usize, y: usize| {
            let p = self.rgba[y * w + x];
            [p[0] * p[3], p[1] * p[3], p[2] * p[3], p[3]]
        };
        let (a, b, c, d) = (
            premultiplied(x0, y0),
            premultiplied(x1, y0),
            premultiplied(x0, y1),
            premultiplied(x1, y1),
        );
        Some(std::array::from_fn(|k| {
            (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy
        }))
    }

    /// The pixel `(u, v)` where this render sees the world direction `dir` from its centre
    /// (pinhole of focal `focal` pixels, OpenGL axes: +x right, +y up, looking along −z).
    fn pixel_of_direction(&self, dir: DVec3, focal: f64) -> Option<(f64, f64)> {
        let col = |j: usize| DVec3::new(self.c2w[0][j], self.c2w[1][j], self.c2w[2][j]);
        let (x, y, z) = (dir.dot(col(0)), dir.dot(col(1)), dir.dot(col(2)));
        let depth = -z;
        (depth > 0.0).then(|| {
            (
                self.size.0 as f64 / 2.0 + focal * x / depth,
                self.size.1 as f64 / 2.0 - focal * y / depth,
            )
        })
    }
}

/// OpenCV world → camera pose of an OpenGL camera → world matrix (the renders' matrices are
/// single precision: the rotation is made exactly orthonormal through its quaternion).
fn opencv_pose(c2w: &[[f64; 4]; 4]) -> ColmapPose {
    let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
    let rotation = DMat3::from_cols(col(0), -col(1), -col(2)).transpose();
    let rotation = DMat3::from_quat(DQuat::from_mat3(&rotation).normalize());
    ColmapPose {
        rotation,
        translation: -(rotation * col(3)),
    }
}

/// The world moved by `X' = s·R·X + t`: a pose that saw `X` sees `X'` at the same pixel,
/// `R_c' = R_c Rᵀ`, `t_c' = s·t_c − R_c' t` (its distances scaled by `s`).
fn regauge(pose: &ColmapPose, (rotation, translation, scale): (DMat3, DVec3, f64)) -> ColmapPose {
    let r = pose.rotation * rotation.transpose();
    ColmapPose {
        rotation: r,
        translation: scale * pose.translation - r * translation,
    }
}

fn read_renders(lego: &Path) -> Result<(Vec<(String, Render)>, f64)> {
    let path = lego.join("transforms_train.json");
    let text = std::fs::read_to_string(&path).with_context(|| format!("{}", path.display()))?;
    let json: serde_json::Value = serde_json::from_str(&text)?;
    let fov = json["camera_angle_x"].as_f64().context("camera_angle_x")?;
    let frames = json["frames"].as_array().context("frames")?;
    let renders = frames
        .iter()
        .map(|f| {
            let name = f["file_path"].as_str().context("file_path")?;
            let name = name.trim_start_matches("./");
            let m = f["transform_matrix"]
                .as_array()
                .context("transform_matrix")?;
            let c2w = std::array::from_fn(|i| {
                std::array::from_fn(|j| m[i][j].as_f64().unwrap_or(f64::NAN))
            });
            let file = lego.join(format!("{name}.png"));
            let image = image::open(&file)
                .with_context(|| format!("{}", file.display()))?
                .to_rgba32f();
            let size = (image.width() as usize, image.height() as usize);
            let rgba = image.pixels().map(|p| p.0).collect();
            let stem = Path::new(name).file_name().unwrap_or_default();
            Ok((
                stem.to_string_lossy().to_string(),
                Render { size, rgba, c2w },
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((renders, fov))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let flag = |f: &str| args.iter().any(|a| a == f);
    let positional: Vec<&String> = args
        .iter()
        .enumerate()
        .filter(|(i, a)| !a.starts_with("--") && (*i == 0 || args[i - 1] != "--size"))
        .map(|(_, a)| a)
        .collect();
    let [lego, out] = positional[..] else {
        bail!("usage: distorted_capture LEGO_DIR OUT [--size N] [--pinhole] [--binary] [--white]");
    };
    let side: usize = match args.iter().position(|a| a == "--size") {
        Some(i) => args.get(i + 1).context("--size N")?.parse()?,
        None => 200,
    };
    let (lego, out) = (PathBuf::from(lego), PathBuf::from(out));
    let (renders, fov) = read_renders(&lego)?;
    let render_focal = 0.5 * renders[0].1.size.0 as f64 / (0.5 * fov).tan();
    let focal = FOCAL_SCALE * 0.5 * side as f64 / (0.5 * fov).tan();
    let c = side as f64 / 2.0;
    let (model_name, params) = if flag("--pinhole") {
        ("PINHOLE", vec![focal, focal, c, c])
    } else {
        let [k1, k2, p1, p2] = DISTORTION;
        ("OPENCV", vec![focal, focal, c, c, k1, k2, p1, p2])
    };
    // An arbitrary gauge: a turn of 40° about a tilted axis, a shift and a scale of 3.7.
    let gauge = (
        DMat3::from_axis_angle(DVec3::new(0.3, -0.5, 0.8).normalize(), 0.7),
        DVec3::new(12.0, -4.5, 30.0),
        3.7,
    );
    let images_dir = out.join("images");
    std::fs::create_dir_all(&images_dir)?;
    let (mut images, mut outside) = (Vec::new(), 0usize);
    for (i, (stem, render)) in renders.iter().enumerate() {
        let pose = opencv_pose(&render.c2w);
        let camera = ColmapCamera::from_colmap(model_name, &params, (side, side), pose)?;
        let mut photo = image::RgbaImage::new(side as u32, side as u32);
        for (x, y, pixel) in photo.enumerate_pixels_mut() {
            let mut sum = [0.0f32; 4];
            for sy in 0..SUPERSAMPLE {
                for sx in 0..SUPERSAMPLE {
                    let u = x as f64 + (sx as f64 + 0.5) / SUPERSAMPLE as f64;
                    let v = y as f64 + (sy as f64 + 0.5) / SUPERSAMPLE as f64;
                    let (_, dir) = camera.ray_through_pixel(u, v);
                    let seen = render
                        .pixel_of_direction(dir, render_focal)
                        .and_then(|(u, v)| render.sample(u, v));
                    outside += usize::from(seen.is_none());
                    let rgba = seen.unwrap_or([0.0; 4]);
                    (0..4).for_each(|k| sum[k] += rgba[k]);
                }
            }
            let alpha = sum[3] / (SUPERSAMPLE * SUPERSAMPLE) as f32;
            // Straight colour: the premultiplied sum over the alpha sum.
            let straight = |k: usize| if sum[3] > 0.0 { sum[k] / sum[3] } else { 0.0 };
            let byte = |v: f32| (v * 255.0).round().clamp(0.0, 255.0) as u8;
            pixel.0 = [
                byte(straight(0)),
                byte(straight(1)),
                byte(straight(2)),
                byte(alpha),
            ];
        }
        let name = match flag("--white") {
            true => {
                let name = format!("{stem}.jpg");
                let on_white = image::RgbImage::from_fn(side as u32, side as u32, |x, y| {
                    let [r, g, b, a] = photo.get_pixel(x, y).0.map(|v| v as f32 / 255.0);
                    let over = |c: f32| ((c * a + 1.0 - a) * 255.0).round() as u8;
                    image::Rgb([over(r), over(g), over(b)])
                });
                let file = std::fs::File::create(images_dir.join(&name))?;
                let mut jpeg = image::codecs::jpeg::JpegEncoder::new_with_quality(file, 95);
                jpeg.encode_image(&on_white)?;
                name
            }
            false => {
                let name = format!("{stem}.png");
                photo.save(images_dir.join(&name))?;
                name
            }
        };
        let moved = regauge(&pose, gauge);
        let q = DQuat::from_mat3(&moved.rotation);
        images.push(ColmapImage {
            id: i as u32 + 1,
            qvec: [q.w, q.x, q.y, q.z],
            tvec: moved.translation.to_array(),
            camera_id: 1,
            name,
            points2d: Vec::new(),
        });
    }
    let camera = colmap::ColmapCameraRecord {
        id: 1,
        model: model_name.to_string(),
        width: side as u64,
        height: side as u64,
        params,
    };
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let model = ColmapModel {
        cameras: [(1, camera)].into(),
        images,
        points: Vec::new(),
    };
    let sparse = out.join("sparse").join("0");
    if flag("--binary") {
        colmap::write_binary(&sparse, &model)?;
    } else {
        colmap::write_text(&sparse, &model)?;
    }
    println!(
        "wrote {} {side}x{side} {model_name} photos and their COLMAP model to {} ({} of {} rays \
         fell outside their render and read transparent)",
        model.images.len(),
        out.display(),
        outside,
        renders.len() * side * side * SUPERSAMPLE * SUPERSAMPLE
    );
    Ok(())
}
