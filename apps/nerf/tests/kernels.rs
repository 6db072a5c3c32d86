//! Fused CPU kernels against their generic tensor-op twins: gradients of a rendered image with
//! respect to every NeRF weight, and whole renders through the binary's `--kernels` switch.

mod common;

use candle_core::{Device, Tensor};
use common::{max_abs_diff, nerf_ok, read_npy};
use nerf::config::Config;
use nerf::core::rays::Rays;
use nerf::render::occupied_field::OccupiedField;
use nerf::{named_vars, with_kernel_choice, KernelChoice, NerfState};

/// `d(Σ colour + Σ depth)/d(weight)` for every NeRF parameter, with `choice` in force.
fn nerf_gradients(config: &Config, choice: KernelChoice) -> Vec<(String, Vec<f32>)> {
    with_kernel_choice(choice, || {
        let device = Device::Cpu;
        let state = NerfState::seeded(&config.nerf_params().unwrap(), 11, &device).unwrap();
        // The weights as variables, rendered through the config's grid when it has one.
        let field: Box<dyn nerf::Field> = match config.occupancy_grid() {
            Some(g) => Box::new(OccupiedField {
                field: Box::new(state.training_field(0.0)),
                grid: std::sync::Arc::new(nerf::OccupancyGrid::new(&g).unwrap()),
            }),
            None => Box::new(state.training_field(0.0)),
        };
        let cam = config.surround_cameras()[1];
        let rays = Rays::for_image(&nerf::Camera::from(cam), 7, 5, &device).unwrap();
        let out = config
            .renderer()
            .unwrap()
            .render(&*field, config.sampler().unwrap().as_ref(), &rays, None)
            .unwrap();
        let loss = (out.color.sum_all().unwrap() + out.depth.sum_all().unwrap()).unwrap();
        let grads = loss.backward().unwrap();
        named_vars(&state.varmap)
            .into_iter()
            .map(|(name, var)| {
                let g = grads
                    .get(var.as_tensor())
                    .unwrap_or_else(|| panic!("{choice:?}: no gradient for {name}"));
                (name, g.flatten_all().unwrap().to_vec1::<f32>().unwrap())
            })
            .collect()
    })
}

#[test]
fn nerf_weight_gradients_agree_between_fused_and_generic_kernels() {
    for extra in [
        &[][..],
        &[
            "renderer.early_termination=1e-4",
            "renderer.occupancy_grid.resolution=8",
        ][..],
    ] {
        let mut overrides = vec![
            "implicit_function.n_hidden_neurons_xyz=32".to_string(),
            "implicit_function.n_hidden_neurons_dir=16".to_string(),
            "sampler.n_pts_per_ray=24".to_string(),
        ];
        overrides.extend(extra.iter().map(|s| s.to_string()));
        let config = Config::load("nerf_lego", &overrides).unwrap();
        let fused = nerf_gradients(&config, KernelChoice::Fused);
        let generic = nerf_gradients(&config, KernelChoice::Generic);
        assert_eq!(fused.len(), generic.len());
        for ((name, a), (_, b)) in fused.iter().zip(&generic) {
            let scale = b.iter().fold(1f32, |m, v| m.max(v.abs()));
            let diff = max_abs_diff(a, b);
            assert!(
                diff <= 1e-5 * scale,
                "{name} ({extra:?}): fused and generic gradients differ by {diff} (scale {scale})"
            );
        }
    }
}

#[test]
fn fused_kernels_see_a_different_graph_than_generic_ones() {
    // The switch really changes the path: the generic trunk records per-layer matmuls, the
    // fused one a single custom op, yet both give the same values (checked above).
    let x = Tensor::ones((3, 2), candle_core::DType::F32, &Device::Cpu).unwrap();
    assert!(with_kernel_choice(KernelChoice::Fused, || {
        nerf::kernels::use_fused(&x)
    }));
    assert!(!with_kernel_choice(KernelChoice::Generic, || {
        nerf::kernels::use_fused(&x)
    }));
}

/// `nerf [--kernels K] render ... --raw` into a fresh directory; the frames' colour and depth.
fn raw_render(kernels: &str, args: &[&str]) -> Vec<(Vec<f32>, Vec<f32>)> {
    let (_dir, out) = common::scratch("out");
    let mut full = vec!["--kernels", kernels, "render"];
    full.extend(args);
    full.extend(["--raw", "--out-dir", out.to_str().unwrap()]);
    nerf_ok(&full);
    let mut frames = Vec::new();
    for i in 0.. {
        let c = out.join(format!("color_{i:03}.npy"));
        if !c.exists() {
            break;
        }
        frames.push((
            read_npy(&c).1,
            read_npy(&out.join(format!("depth_{i:03}.npy"))).1,
        ));
    }
    assert!(!frames.is_empty());
    frames
}

fn assert_renders_agree(args: &[&str]) {
    let fused = raw_render("fused", args);
    let generic = raw_render("generic", args);
    assert_eq!(fused.len(), generic.len());
    for (i, ((fc, fd), (gc, gd))) in fused.iter().zip(&generic).enumerate() {
        let (c, d) = (max_abs_diff(fc, gc), max_abs_diff(fd, gd));
        assert!(
            c <= 1e-5 && d <= 1e-5,
            "{args:?} frame {i}: colour {c}, depth {d}"
        );
    }
}

#[test]
fn box_renders_agree_between_fused_and_generic_kernels() {
    assert_renders_agree(&[
        "--config",
        "box",
        "data.image_size=[48,40]",
        "cameras.n_poses=4",
    ]);
}

#[test]
fn lego_renders_agree_between_fused_and_generic_kernels() {
    // The shipped checkpoint, with its occupancy grid and early termination, at a small size.
    assert_renders_agree(&[
        "--config",
        "lego",
        "data.image_size=[32,32]",
        "cameras.n_poses=2",
    ]);
}
