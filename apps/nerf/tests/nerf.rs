//! NeRF training tests: loss goes down, gradients reach every parameter, checkpoints
//! round-trip bit-exactly, and a resumed run ends where an uninterrupted one does.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
mod common;

use nerf::config::Config;
use nerf::field::nerf::parameter_shapes;
use nerf::io::checkpoint::{self, CheckpointInfo};
use nerf::io::dataset::{Dataset, Frame};
use nerf::train::model::{Optimizer, TrainModel};
use nerf::train::step::train_step;
use nerf::{render_view, NerfParams, NerfState, Pipeline};
use rand::SeedableRng;

/// A small NeRF config (the homework's architecture, smaller sizes) with overrides.
fn tiny_config(extra: &[&str]) -> Config {
    let mut o: Vec<String> = [
        "data.image_size=[12,12]",
        "sampler.n_pts_per_ray=16",
        "training.batch_size=64",
        "implicit_function.n_hidden_neurons_xyz=32",
        "implicit_function.n_hidden_neurons_dir=16",
        "implicit_function.n_layers_xyz=4",
        "implicit_function.append_xyz=[2]",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    o.extend(extra.iter().map(|s| s.to_string()));
    Config::load("nerf_lego", &o).unwrap()
}

/// Ground truth rendered from the box SDF, seen by NeRF-style cameras (radius 4, z up).
fn box_dataset(config: &Config) -> Dataset {
    let box_config = Config::load("box", &["data.image_size=[12,12]".into()]).unwrap();
    let field = box_config.sdf_field(&Device::Cpu).unwrap();
    let sampler = box_config.sampler().unwrap();
    let renderer = box_config.renderer().unwrap();
    let cameras = config.surround_cameras();
    let mut frames = Vec::new();
    let mut images = Vec::new();
    for cam in cameras.iter().take(4) {
        let pipeline = Pipeline::new(&field, &*sampler, &renderer);
        let f = render_view(&pipeline, &nerf::Camera::from(*cam), (12, 12), &Device::Cpu).unwrap();
        frames.push(Frame {
            file_path: PathBuf::from("synthetic"),
            camera: (*cam).into(),
            mask_path: None,
        });
        images.push(f.color);
    }
    Dataset {
        frames,
        images,
        transparency: Vec::new(),
        width: 12,
        height: 12,
        masks: Vec::new(),
        normalisation: None,
        capture: None,
    }
}

/// A NeRF of `params` from the checkpoint at `path` (either format), and its progress.
fn load_nerf(params: &NerfParams, path: &Path) -> anyhow::Result<(NerfState, CheckpointInfo)> {
    let shapes = parameter_shapes(params);
    let (tensors, info) = nerf::io::checkpoint_file::load(path, &shapes, &Device::Cpu)?;
    Ok((NerfState::from_tensors(params, &tensors, path)?, info))
}

fn named_vars(state: &NerfState) -> Vec<(String, candle_core::Var)> {
    let data = state.varmap.data().lock().unwrap();
    let mut v: Vec<_> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn a_few_steps_lower_the_loss() {
    let config = tiny_config(&["training.lr=0.005"]);
    let dataset = box_dataset(&config);
    let nerf_cfg = config.nerf_params().unwrap();
    let state = TrainModel::seeded(&nerf_cfg, 0, &Device::Cpu).unwrap();
    let mut adam = Optimizer::new(&state, 0.005).unwrap();
    let mut rng = nerf::train::step::TrainRng::seed_from_u64(5);
    let mut losses = Vec::new();
    for step in 0..60 {
        losses.push(
            train_step(
                &state,
                &config.train_settings().unwrap().step,
                &dataset,
                step % 4,
                &mut adam,
                &mut rng,
                &Device::Cpu,
            )
            .unwrap()
            .0,
        );
    }
    let first: f64 = losses[..10].iter().sum::<f64>() / 10.0;
    let last: f64 = losses[50..].iter().sum::<f64>() / 10.0;
    eprintln!("mean loss first 10 steps {first:.4}, last 10 steps {last:.4}");
    assert!(last < 0.7 * first, "loss did not fall: {first} -> {last}");
}

#[test]
fn gradients_reach_every_parameter() {
    // Dense rendering, and the skipping path (occupancy grid + early termination), which
    // scatters the packed samples back with index_add.
    for accelerated in [false, true] {
        let extra: &[&str] = if accelerated {
            &[
                "renderer.early_termination=1e-4",
                "renderer.occupancy_grid.resolution=8",
            ]
        } else {
            &[]
        };
        let config = tiny_config(extra);
        let nerf_cfg = config.nerf_params().unwrap();
        let state = NerfState::new(&nerf_cfg, &Device::Cpu).unwrap();
        // The weights as variables, rendered through the config's grid when it has one.
        let field: Box<dyn nerf::Field> = match config.occupancy_grid() {
            Some(g) => Box::new(nerf::render::occupied_field::OccupiedField {
                field: Box::new(state.training_field(0.0)),
                grid: std::sync::Arc::new(nerf::OccupancyGrid::new(&g).unwrap()),
            }),
            None => Box::new(state.training_field(0.0)),
        };
        let cam = config.surround_cameras()[0];
        let rays = nerf::core::rays::Rays::for_image(&nerf::Camera::from(cam), 6, 6, &Device::Cpu)
            .unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(1);
        let out = config
            .renderer()
            .unwrap()
            .render(
                &*field,
                config.sampler().unwrap().as_ref(),
                &rays,
                Some(&mut rng),
            )
            .unwrap();
        let loss = (out.color.sum_all().unwrap() + out.depth.sum_all().unwrap()).unwrap();
        let grads = loss.backward().unwrap();
        for (name, var) in named_vars(&state) {
            let g = grads
                .get(var.as_tensor())
                .unwrap_or_else(|| panic!("no gradient for {name}"));
            let norm = g
                .sqr()
                .unwrap()
                .sum_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap();
            assert!(
                norm.is_finite() && norm > 0.0,
                "{name} (accelerated {accelerated}): gradient norm {norm}"
            );
        }
    }
}

#[test]
fn fast_training_lowers_the_loss_and_keeps_the_grid_current() {
    // Every extension of nerf_lego_fast on: rays from all images, random backgrounds,
    // occupancy grid updates and early termination.
    let config = tiny_config(&[
        "training.lr=0.005",
        "training.rays_from_all_images=true",
        "training.random_background=true",
        "renderer.early_termination=1e-4",
        "renderer.occupancy_grid.resolution=8",
        "renderer.occupancy_grid.update_interval=4",
        "renderer.occupancy_grid.warmup_steps=8",
    ]);
    let dataset = box_dataset(&config);
    let nerf_cfg = config.nerf_params().unwrap();
    let mut state = TrainModel::seeded(&nerf_cfg, 0, &Device::Cpu).unwrap();
    let settings = config.occupancy_grid().unwrap();
    state.occupancy = Some(nerf::OccupancyGrid::new(&settings).unwrap());
    let mut adam = Optimizer::new(&state, 0.005).unwrap();
    let mut rng = nerf::train::step::TrainRng::seed_from_u64(5);
    let mut losses = Vec::new();
    for step in 0..60 {
        if step % 4 == 0 {
            state
                .update_grid(step < 8, 0.95, &mut rng, &Device::Cpu)
                .unwrap();
        }
        let (loss, samples) = train_step(
            &state,
            &config.train_settings().unwrap().step,
            &dataset,
            0,
            &mut adam,
            &mut rng,
            &Device::Cpu,
        )
        .unwrap();
        assert!(samples.evaluated <= samples.total);
        losses.push(loss);
    }
    let first: f64 = losses[..10].iter().sum::<f64>() / 10.0;
    let last: f64 = losses[50..].iter().sum::<f64>() / 10.0;
    let grid = state.occupancy.as_ref().unwrap();
    eprintln!(
        "loss {first:.4} -> {last:.4}; {:.1}% of cells occupied",
        100.0 * grid.occupied_fraction()
    );
    assert!(last < 0.7 * first, "loss did not fall: {first} -> {last}");
    // Warm-up probed every cell; the flags follow the running densities.
    assert!(grid
        .density
        .iter()
        .all(|d| d.is_finite() && *d >= 0.0 && *d < f32::MAX));
    let mean = grid.density.iter().map(|&d| d as f64).sum::<f64>() / grid.n_cells() as f64;
    let cut = (grid.density_threshold as f64).min(mean) as f32;
    for (d, o) in grid.density.iter().zip(&grid.occupied) {
        assert_eq!(*o, *d > cut);
    }
}

#[test]
fn batches_from_all_images_pair_rays_with_their_pixels() {
    let config = tiny_config(&[]);
    let dataset = box_dataset(&config);
    let mut rng = nerf::train::step::TrainRng::seed_from_u64(3);
    let (rays, target, transparency) =
        nerf::train::step::training_batch(&dataset, 50, true, 0, &mut rng, &Device::Cpu).unwrap();
    assert_eq!(rays.len(), 50);
    assert_eq!(target.dims(), &[50, 3]);
    assert_eq!(transparency.dims(), &[50, 1]);
    let origins = rays.origins.to_vec2::<f32>().unwrap();
    let directions = rays.directions.to_vec2::<f32>().unwrap();
    let target = target.to_vec2::<f32>().unwrap();
    let mut images_seen = std::collections::HashSet::new();
    for k in 0..50 {
        // Find the image by its camera centre and the pixel by its ray direction.
        let (image, all) = (0..dataset.frames.len())
            .map(|i| {
                let r = nerf::core::rays::Rays::for_image(
                    &dataset.frames[i].camera,
                    12,
                    12,
                    &Device::Cpu,
                )
                .unwrap();
                (i, r)
            })
            .find(|(_, r)| {
                let o = r.origins.to_vec2::<f32>().unwrap();
                o[0].iter()
                    .zip(&origins[k])
                    .all(|(a, b)| (a - b).abs() < 1e-5)
            })
            .expect("ray from a training camera");
        images_seen.insert(image);
        let dirs = all.directions.to_vec2::<f32>().unwrap();
        let pixel = dirs
            .iter()
            .position(|d| {
                d.iter()
                    .zip(&directions[k])
                    .all(|(a, b)| (a - b).abs() < 1e-6)
            })
            .expect("ray through a pixel");
        let expected = &dataset.images[image].data[3 * pixel..3 * pixel + 3];
        assert_eq!(&target[k][..], expected);
    }
    assert!(images_seen.len() > 1, "all rays came from one image");
}

#[test]
fn checkpoint_round_trips_bit_exactly() {
    let config = tiny_config(&[]);
    let nerf_cfg = config.nerf_params().unwrap();
    let state = NerfState::new(&nerf_cfg, &Device::Cpu).unwrap();
    let (_dir, path) = common::scratch("m.safetensors");
    let info = CheckpointInfo {
        epoch: 7,
        adam_step: 700,
        wall_seconds: 12.5,
        step_in_epoch: 3,
        rng_word_pos: 1 << 70,
        rays_per_step: 3000,
        scene_transform: None,
        capture_orbit: Some(nerf::io::dataset::CaptureOrbit {
            radius: 0.8123,
            height: -0.25,
            focal: [2.7777, 1.5],
        }),
        capture_spiral: Some(nerf::io::dataset::CaptureSpiral {
            centre: glam::DVec3::new(0.1, -0.2, 0.3),
            forward: glam::DVec3::Y,
            up: glam::DVec3::Z,
            radii: [0.4, 0.25, 0.05],
            focus_distance: 2.5,
            focal: [1.2, 1.6],
        }),
        background: Some([0.1, 0.5, 1.0]),
        image_size: Some((320, 180)),
        sample_depths: Some((0.625, 1.375)),
        object_box: Some([-0.375, -0.25, -0.5, 0.375, 0.5, 0.25]),
        field_layout: Some("a layout line".to_string()),
    };
    checkpoint::save(
        &path,
        &checkpoint::model_tensors(&state.varmap),
        info.clone(),
    )
    .unwrap();
    let (loaded, back) = load_nerf(&nerf_cfg, &path).unwrap();
    assert_eq!(back, info);
    let a: HashMap<String, Tensor> = checkpoint::model_tensors(&state.varmap)
        .into_iter()
        .collect();
    for (name, t) in checkpoint::model_tensors(&loaded.varmap) {
        let x = a[&name].flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let y = t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(
            x.iter().zip(&y).all(|(p, q)| p.to_bits() == q.to_bits()),
            "{name} differs"
        );
    }
    // A model of another width is refused with the tensor and both shapes named.
    let wide = tiny_config(&["implicit_function.n_hidden_neurons_xyz=48"]);
    let err = load_nerf(&wide.nerf_params().unwrap(), &path)
        .err()
        .unwrap();
    let msg = format!("{err:#}");
    assert!(
        msg.contains("mlp_xyz.mlp.0.0.weight")
            && msg.contains("[32, 39]")
            && msg.contains("[48, 39]"),
        "{msg}"
    );
}

fn lego_dir() -> Option<PathBuf> {
    common::lego_dir()
}

fn weights_of(path: &Path) -> HashMap<String, Vec<f32>> {
    let (t, _) = checkpoint::load(path, &Device::Cpu).unwrap();
    t.into_iter()
        .map(|(k, v)| (k, v.flatten_all().unwrap().to_vec1::<f32>().unwrap()))
        .collect()
}

/// The resume tests' small runs: 8×8 images, 8 samples a ray, 16 rays a batch and a
/// checkpoint after every epoch.
const SMALL_RUN: [&str; 4] = [
    "data.image_size=[8,8]",
    "sampler.n_pts_per_ray=8",
    "training.batch_size=16",
    "training.checkpoint_interval=1",
];

/// Trains the config `name` with [`SMALL_RUN`], `overrides` and
/// `training.checkpoint_path=<checkpoint>` on the lego data in `data` (its images under
/// `dir/images`) within `limits`, through `nerf train` on the CPU; returns the checkpoint's
/// path (the file, as the trainer resolves a directory).
fn train_lego(
    name: &str,
    overrides: &[&str],
    checkpoint: &Path,
    dir: &Path,
    data: &Path,
    limits: nerf::RunLimits,
) -> PathBuf {
    let images = dir.join("images");
    let checkpoint_key = format!("training.checkpoint_path={}", checkpoint.display());
    let epochs = limits.epochs.map(|e| e.to_string());
    // `--minutes` must be positive: a limit of 0 s is the smallest positive one, which also
    // stops after the first step.
    let minutes = limits.seconds.map(|s| (s / 60.0).max(1e-12).to_string());
    let mut args = common::data_args(
        "train",
        name,
        data,
        &["--out-dir", images.to_str().unwrap()],
    );
    if let Some(e) = &epochs {
        args.extend(["--epochs", e]);
    }
    if let Some(m) = &minutes {
        args.extend(["--minutes", m]);
    }
    args.extend(SMALL_RUN.iter().chain(overrides));
    args.push(&checkpoint_key);
    common::nerf_ok(&args);
    let config = Config::load(name, std::slice::from_ref(&checkpoint_key)).unwrap();
    config.train_paths(&images).unwrap().checkpoint
}

#[test]
fn resume_continues_exactly() {
    let Some(data) = lego_dir() else { return };
    let base = [
        "training.num_epochs=4",
        "training.render_interval=1000",
        "implicit_function.n_hidden_neurons_xyz=16",
        "implicit_function.n_hidden_neurons_dir=8",
        "implicit_function.n_layers_xyz=3",
        "implicit_function.append_xyz=[2]",
    ];
    let run = |dir: &Path, stop: Option<usize>| {
        let limits = nerf::RunLimits {
            epochs: stop,
            seconds: None,
        };
        train_lego("nerf_lego", &base, dir, dir, &data, limits)
    };
    let straight = tempfile::tempdir().unwrap();
    let a = run(straight.path(), None);
    let split = tempfile::tempdir().unwrap();
    let half = run(split.path(), Some(2));
    assert_eq!(checkpoint::load(&half, &Device::Cpu).unwrap().1.epoch, 2);
    // As if the run had been killed mid-epoch: steps logged after the last checkpoint.
    let log_path = split.path().join("nerf_lego.log.jsonl");
    let mut log = std::fs::read_to_string(&log_path).unwrap();
    log += "{\"step\":201,\"epoch\":2,\"wall_s\":1.0,\"loss\":0.1,\"psnr\":10.0}\n";
    std::fs::write(&log_path, log).unwrap();
    let b = run(split.path(), None);
    // The resumed log holds each of the 4 × 100 steps exactly once, in order.
    let steps = common::logged_steps(split.path());
    assert_eq!(steps, (1..=400).collect::<Vec<_>>());
    let (wa, wb) = (weights_of(&a), weights_of(&b));
    assert_eq!(checkpoint::load(&b, &Device::Cpu).unwrap().1.epoch, 4);
    for (name, x) in &wa {
        let y = &wb[name];
        let diff = x
            .iter()
            .zip(y)
            .map(|(p, q)| (p - q).abs())
            .fold(0f32, f32::max);
        assert!(diff <= 1e-5, "{name}: resumed run differs by {diff}");
    }
}

#[test]
fn nerf_render_does_not_depend_on_chunking() {
    let config = tiny_config(&[]);
    let nerf_cfg = config.nerf_params().unwrap();
    let state = NerfState::seeded(&nerf_cfg, 3, &Device::Cpu).unwrap();
    let cam = config.surround_cameras()[5];
    let sampler = config.sampler().unwrap();
    let render = |chunk: usize| {
        let renderer = nerf::render::renderer::VolumeRenderer::new(chunk, false).unwrap();
        let field = state.field();
        render_view(
            &Pipeline::new(&field, &*sampler, &renderer),
            &nerf::Camera::from(cam),
            (10, 9),
            &Device::Cpu,
        )
        .unwrap()
    };
    let (a, b) = (render(7), render(32768));
    let diff = a
        .color
        .data
        .iter()
        .zip(&b.color.data)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    // Matrix products may block differently for different row counts: float noise only.
    assert!(diff < 1e-5, "chunking changed the image by {diff}");
}

fn fixtures() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../..")).join("tests/fixtures")
}

#[test]
fn pytorch_state_dicts_import_and_match_pytorch_outputs() {
    // Made by scripts/make_torch_state_dict.py: a tiny homework NeRF saved by torch.save, and
    // PyTorch's float64 density and colour at 16 points.
    let config = Config::load(fixtures().join("tiny_nerf.yaml").to_str().unwrap(), &[]).unwrap();
    let nerf_cfg = config.nerf_params().unwrap();
    let (expected, _) = checkpoint::load(
        &fixtures().join("tiny_nerf_outputs.safetensors"),
        &Device::Cpu,
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    for pth in ["tiny_nerf.pth", "tiny_nerf_nested.pth"] {
        let out = dir.path().join(format!("{pth}.safetensors"));
        nerf::io::torch::import_torch(&fixtures().join(pth), &parameter_shapes(&nerf_cfg), &out)
            .unwrap();
        let (state, info) = load_nerf(&nerf_cfg, &out).unwrap();
        assert_eq!(info.epoch, 0);
        let points = expected["points"].unsqueeze(1).unwrap();
        let out = state
            .model
            .forward(&points, &expected["directions"], 0.0)
            .unwrap();
        let diff = |a: &Tensor, b: &Tensor| nerf::core::compare::max_abs_difference(a, b).unwrap();
        let (d, c) = (
            diff(&out.density, &expected["density"]),
            diff(&out.feature, &expected["colour"]),
        );
        eprintln!("{pth}: max density error {d:.1e}, max colour error {c:.1e}");
        assert!(d < 1e-5 && c < 1e-6, "{pth}: {d} {c}");
        // Some densities are positive, so the comparison covers the density head.
        let positive = expected["density"]
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap()
            .iter()
            .filter(|v| **v > 0.0)
            .count();
        assert!(positive > 4);
    }
}

#[test]
fn pytorch_state_dict_of_the_wrong_size_names_the_tensor() {
    // The homework-size config against the tiny state dict.
    let config = Config::load("nerf_lego", &[]).unwrap();
    let nerf_cfg = config.nerf_params().unwrap();
    let (dir, out) = common::scratch("x.safetensors");
    let err = nerf::io::torch::import_torch(
        &fixtures().join("tiny_nerf.pth"),
        &parameter_shapes(&nerf_cfg),
        &out,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("mlp_xyz.mlp.0.0.weight") && err.contains("[128, 39]"),
        "{err}"
    );
    assert!(!out.exists());
    let missing = nerf::io::torch::import_torch(
        &dir.path().join("none.pth"),
        &parameter_shapes(&nerf_cfg),
        &out,
    )
    .unwrap_err()
    .to_string();
    assert!(missing.contains("not found"), "{missing}");
}

#[test]
fn ngp_training_resumes_exactly_after_a_time_limit() {
    let Some(data) = lego_dir() else { return };
    let base = [
        "training.num_epochs=2",
        "training.eval_views=0",
        "renderer.occupancy_grid.resolution=8",
        "renderer.occupancy_grid.update_interval=4",
        "renderer.occupancy_grid.warmup_steps=8",
        "implicit_function.n_levels=4",
        "implicit_function.log2_hashmap_size=10",
        "implicit_function.max_resolution=32",
    ];
    let run = |dir: &Path, seconds: Option<f64>| {
        let limits = nerf::RunLimits {
            epochs: None,
            seconds,
        };
        let checkpoint = dir.join("ngp.safetensors");
        train_lego("nerf_lego_ngp", &base, &checkpoint, dir, &data, limits)
    };
    let straight = tempfile::tempdir().unwrap();
    let a = run(straight.path(), None);
    // A zero time limit stops after the first step, mid-epoch; each resume takes one more.
    let split = tempfile::tempdir().unwrap();
    let first = run(split.path(), Some(0.0));
    let info = checkpoint::load(&first, &Device::Cpu).unwrap().1;
    assert_eq!((info.epoch, info.step_in_epoch, info.adam_step), (0, 1, 1));
    for _ in 0..3 {
        run(split.path(), Some(0.0));
    }
    let b = run(split.path(), None);
    let (wa, wb) = (weights_of(&a), weights_of(&b));
    assert_eq!(checkpoint::load(&b, &Device::Cpu).unwrap().1.adam_step, 200);
    // Every tensor (model, both optimisers' state including each table row's step count,
    // the occupancy grid) is bit-identical to the uninterrupted run's.
    assert!(wa.contains_key("adam.row_steps.encoding.table"));
    assert_eq!(wa.keys().len(), wb.keys().len());
    for (name, x) in &wa {
        assert!(x == &wb[name], "{name}: resumed run differs");
    }
    // The sparse optimiser left rows no sample touched exactly at their initial values.
    let steps = &wa["adam.row_steps.encoding.table"];
    assert!(steps.contains(&0.0) && steps.iter().any(|&s| s > 0.0));
}
