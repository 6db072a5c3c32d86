//! Captures of the first lego training views in the formats other NeRF tools read (COLMAP
//! text, nerfstudio `transforms.json`, LLFF `poses_bounds.npy`), written by hand here,
//! independent of the loaders, for apps/nerf/tests/captures.rs and apps/nerf/tests/capture_inputs.rs.

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};

pub const FRAMES: usize = 16;

/// One lego training view: image, camera → world (Blender/OpenGL axes), image size.
pub struct View {
    pub image: PathBuf,
    pub c2w: [[f64; 4]; 4],
}

pub struct Lego {
    pub views: Vec<View>,
    pub fov: f64,
    pub size: (u32, u32),
}

pub fn lego() -> Option<Lego> {
    lego_views(FRAMES)
}

/// The first `n` (at most 100) lego training views, or a visible skip.
pub fn lego_views(n: usize) -> Option<Lego> {
    let dir = super::lego_dir()?;
    let text = std::fs::read_to_string(dir.join("transforms_train.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let fov = json["camera_angle_x"].as_f64().unwrap();
    let views: Vec<View> = json["frames"]
        .as_array()
        .unwrap()
        .iter()
        .take(n)
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
    pub fn first(&self, n: usize) -> Lego {
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

    /// The same views with the cameras of the training split (all but every 8th, the
    /// captures' holdout) each turned by `degrees` about a random axis through its centre and
    /// moved by `shift` times the farthest camera's distance from the origin in a random
    /// direction (seeded by `seed`); the held-out cameras stay exact.
    pub fn perturbed(&self, degrees: f64, shift: f64, seed: u64) -> Lego {
        let centre = |c2w: &[[f64; 4]; 4]| DVec3::new(c2w[0][3], c2w[1][3], c2w[2][3]);
        let radius = self
            .views
            .iter()
            .map(|v| centre(&v.c2w).length())
            .fold(0.0, f64::max);
        let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut unit = move || loop {
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                2.0 * (state >> 11) as f64 / (1u64 << 53) as f64 - 1.0
            };
            let v = DVec3::new(next(), next(), next());
            if (0.1..=1.0).contains(&v.length()) {
                return v.normalize();
            }
        };
        let views = self
            .views
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let mut c2w = v.c2w;
                if !i.is_multiple_of(8) {
                    let turn = DQuat::from_axis_angle(unit(), degrees.to_radians());
                    let cols: [DVec3; 3] =
                        std::array::from_fn(|j| turn * DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]));
                    for (i, row) in c2w.iter_mut().take(3).enumerate() {
                        for (v, col) in row.iter_mut().zip(&cols) {
                            *v = col[i];
                        }
                    }
                    let c = centre(&c2w) + unit() * shift * radius;
                    (c2w[0][3], c2w[1][3], c2w[2][3]) = (c.x, c.y, c.z);
                }
                View {
                    image: v.image.clone(),
                    c2w,
                }
            })
            .collect();
        Lego {
            views,
            fov: self.fov,
            size: self.size,
        }
    }

    /// Focal length in pixels: half the width over tan(fov / 2).
    pub fn focal_px(&self) -> f64 {
        0.5 * self.size.0 as f64 / (0.5 * self.fov).tan()
    }

    /// `images/frame_NN.png` copies of the views, in `dir`.
    pub fn copy_images(&self, dir: &Path) -> Vec<String> {
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
pub fn lego_pixel(view: &View, focal: f64, size: (u32, u32), point: DVec3) -> (f64, f64) {
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
pub fn opencv_pose(c2w: &[[f64; 4]; 4]) -> (DMat3, DVec3) {
    let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
    let c2w_cv = DMat3::from_cols(col(0), -col(1), -col(2));
    let r = c2w_cv.transpose();
    (r, -(r * col(3)))
}

pub fn write_colmap_text(lego: &Lego, dir: &Path) {
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

/// The COLMAP model of the text capture `text` ([`write_colmap_text`]) written again as binary
/// files in `dir/sparse/0`, beside copies of the photos; returns the model.
pub fn write_colmap_binary(lego: &Lego, text: &Path, dir: &Path) -> nerf::io::colmap::ColmapModel {
    lego.copy_images(dir);
    let (_, model) = nerf::io::colmap::find_model(text).unwrap();
    nerf::io::colmap::write_binary(&dir.join("sparse").join("0"), &model).unwrap();
    model
}

pub fn write_nerfstudio(lego: &Lego, dir: &Path) {
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

pub fn write_llff(lego: &Lego, dir: &Path) {
    write_llff_for_size(lego, dir, 1.0);
}

/// [`write_llff`] with `[h, w, focal]` written for photos `scale` times the photos' size
/// (LLFF keeps the full-size values beside downscaled photos).
pub fn write_llff_for_size(lego: &Lego, dir: &Path, scale: f64) {
    lego.copy_images(dir);
    let (w, h) = lego.size;
    let mut values = Vec::new();
    for v in &lego.views {
        // Columns (down, right, back, centre, hwf) row by row; down = −up.
        let m = &v.c2w;
        let hwf = [h as f64, w as f64, lego.focal_px()].map(|x| x * scale);
        for (i, extra) in hwf.iter().enumerate() {
            values.extend([-m[i][1], m[i][0], m[i][2], m[i][3], *extra]);
        }
        values.extend([2.0, 6.0]);
    }
    std::fs::write(dir.join("poses_bounds.npy"), npy_rows(&values)).unwrap();
}

/// A float64 `.npy` file of shape `(N, 17)` holding `values` row by row.
pub fn npy_rows(values: &[f64]) -> Vec<u8> {
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

/// The one `error:` line of a run that failed with status 1 (a capture's loader logs what it
/// read on the lines before it), without a panic.
pub fn error_line(o: &std::process::Output) -> String {
    let log = super::stderr(o);
    assert_eq!(o.status.code(), Some(1), "{log}");
    assert!(!log.contains("panicked"), "{log}");
    let errors: Vec<&str> = log.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(errors.len(), 1, "{log}");
    errors[0].to_string()
}

/// The bytes of every file in `dir`, by name.
pub fn files_of(dir: &Path) -> Vec<(String, Vec<u8>)> {
    super::sorted_names(dir)
        .into_iter()
        .map(|n| {
            let bytes = std::fs::read(dir.join(&n)).unwrap();
            (n, bytes)
        })
        .collect()
}

/// The overrides of a small `nerf_scene_bounded` training (24×24 images, 32 samples a ray, no
/// held-out scoring during training) for `epochs` (`training.num_epochs=N`) that writes the
/// checkpoint `checkpoint` (`training.checkpoint_path=P`).
pub fn tiny_scene_overrides<'a>(epochs: &'a str, checkpoint: &'a str) -> [&'a str; 5] {
    [
        "data.image_size=[24,24]",
        epochs,
        "training.eval_views=0",
        "sampler.n_pts_per_ray=32",
        checkpoint,
    ]
}

/// A small training of `config` on a capture ([`tiny_scene_overrides`]) that writes the
/// checkpoint `checkpoint`, and the commands that read that checkpoint.
pub struct TinyScene {
    /// The config trained and read (`nerf_scene`, `nerf_scene_bounded`).
    pub config: &'static str,
    /// The checkpoint written.
    pub checkpoint: PathBuf,
    epochs: String,
    checkpoint_arg: String,
}

impl TinyScene {
    /// `epochs` epochs of `config` into `checkpoint`.
    pub fn new(config: &'static str, checkpoint: PathBuf, epochs: usize) -> Self {
        Self {
            config,
            epochs: format!("training.num_epochs={epochs}"),
            checkpoint_arg: format!("training.checkpoint_path={}", checkpoint.display()),
            checkpoint,
        }
    }

    /// The overrides of every command ([`tiny_scene_overrides`]).
    pub fn overrides(&self) -> [&str; 5] {
        tiny_scene_overrides(&self.epochs, &self.checkpoint_arg)
    }

    /// `nerf COMMAND --config CONFIG --data-dir DIR`, the overrides, then `extra`.
    pub fn args<'a>(&'a self, command: &'a str, dir: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
        let mut args = super::data_args(command, self.config, dir, &self.overrides());
        args.extend(extra);
        args
    }

    /// Runs [`TinyScene::args`] and asserts that it succeeded (a failure shows its stderr).
    pub fn run_ok(&self, command: &str, dir: &Path, extra: &[&str]) -> std::process::Output {
        super::nerf_ok(&self.args(command, dir, extra))
    }
}

/// The views as instant-ngp's `scripts/colmap2nerf.py` writes them: `w` and `h` as floats,
/// both focal forms (`fl_x` and `camera_angle_x`), zero distortion terms, `is_fisheye`,
/// `aabb_scale`, `./`-prefixed paths and a `sharpness` per frame; odd frames carry their own
/// intrinsics (as colmap2nerf writes them for several cameras), with the field of view but no
/// `fl_x`. With `moved = Some((s, o))` every camera centre `p` is written as `s·p + o` (a
/// gauge of its own, as colmap2nerf's recentring gives) and `scale`, `offset` are written too.
pub fn write_colmap2nerf(lego: &Lego, dir: &Path, moved: Option<(f64, [f64; 3])>) {
    let names = lego.copy_images(dir);
    let (w, h) = (lego.size.0 as f64, lego.size.1 as f64);
    let f = lego.focal_px();
    let angle_x = 2.0 * (w / (2.0 * f)).atan();
    let angle_y = 2.0 * (h / (2.0 * f)).atan();
    let (s, o) = moved.unwrap_or((1.0, [0.0; 3]));
    let camera = serde_json::json!({
        "w": w, "h": h, "cx": w / 2.0, "cy": h / 2.0, "camera_angle_y": angle_y,
        "camera_angle_x": angle_x, "fovx": angle_x.to_degrees(), "fovy": angle_y.to_degrees(),
        "k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0, "p1": 0.0, "p2": 0.0, "is_fisheye": false,
    });
    let frames: Vec<serde_json::Value> = lego
        .views
        .iter()
        .zip(&names)
        .enumerate()
        .map(|(i, (v, name))| {
            let mut c2w = v.c2w;
            for (r, offset) in o.iter().enumerate() {
                c2w[r][3] = s * c2w[r][3] + offset;
            }
            let mut frame = serde_json::json!({
                "file_path": format!("./images/{name}"), "sharpness": 100.0 + i as f64,
                "transform_matrix": c2w,
            });
            if i % 2 == 1 {
                frame
                    .as_object_mut()
                    .unwrap()
                    .extend(camera.as_object().unwrap().clone());
            }
            frame
        })
        .collect();
    let mut json = camera.clone();
    let top = json.as_object_mut().unwrap();
    top.insert("fl_x".into(), serde_json::json!(f));
    top.insert("fl_y".into(), serde_json::json!(f));
    top.insert("aabb_scale".into(), serde_json::json!(16));
    top.insert("frames".into(), serde_json::json!(frames));
    if moved.is_some() {
        top.insert("scale".into(), serde_json::json!(s));
        top.insert("offset".into(), serde_json::json!(o));
    }
    let text = serde_json::to_string_pretty(&json).unwrap();
    // colmap2nerf's Python writes whole floats with their point: `"w": 400.0`.
    assert!(text.contains(&format!("\"w\": {w:.1}")), "{text}");
    std::fs::write(dir.join("transforms.json"), text).unwrap();
}

/// The first `n` lego training views and a scratch directory a test writes its captures,
/// checkpoints and outputs into.
pub struct LegoRoot {
    /// The views ([`lego_views`]).
    pub lego: Lego,
    /// The scratch directory, removed when the test ends.
    pub root: tempfile::TempDir,
}

impl LegoRoot {
    /// `name` inside the scratch directory.
    pub fn path(&self, name: &str) -> PathBuf {
        self.root.path().join(name)
    }

    /// The views written as a COLMAP text capture in the folder `name`, which it returns.
    pub fn colmap_text(&self, name: &str) -> PathBuf {
        let dir = self.path(name);
        write_colmap_text(&self.lego, &dir);
        dir
    }

    /// A [`TinyScene`] of `config` for `epochs` that writes `scene.safetensors` here.
    pub fn tiny_scene(&self, config: &'static str, epochs: usize) -> TinyScene {
        TinyScene::new(config, self.path("scene.safetensors"), epochs)
    }
}

/// The first `n` lego training views ([`lego_views`]) and a fresh scratch directory for the
/// test's captures, or a visible skip.
pub fn lego_root(n: usize) -> Option<LegoRoot> {
    Some(LegoRoot {
        lego: lego_views(n)?,
        root: tempfile::tempdir().unwrap(),
    })
}

/// Applies `change` to the JSON of `dir/transforms.json`, which it returns.
pub fn edit_transforms(dir: &Path, change: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let json = dir.join("transforms.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    change(&mut v);
    std::fs::write(&json, v.to_string()).unwrap();
    json
}

/// Replaces the first line of the text file `path` that `pick` chooses by `change` of it;
/// returns `path`.
pub fn edit_line(
    path: PathBuf,
    pick: impl Fn(&str) -> bool,
    change: impl FnOnce(&str) -> String,
) -> PathBuf {
    let text = std::fs::read_to_string(&path).unwrap();
    let line = text.lines().find(|l| pick(l)).unwrap();
    std::fs::write(&path, text.replacen(line, &change(line), 1)).unwrap();
    path
}

/// Writes the checkpoint `from`'s tensors (sorted by name) again at `to`, with its metadata
/// changed by `edit`.
pub fn resave_checkpoint(from: &Path, to: &Path, edit: impl FnOnce(&mut nerf::CheckpointInfo)) {
    let (tensors, mut info) = nerf::io::checkpoint::load(from, &candle_core::Device::Cpu).unwrap();
    let mut tensors: Vec<_> = tensors.into_iter().collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    edit(&mut info);
    nerf::io::checkpoint::save(to, &tensors, info).unwrap();
}
