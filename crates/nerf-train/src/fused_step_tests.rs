//! The hash-grid field's fused training step ([`nerf_field::fused_step`]) against its twin,
//! the same step through autograd ([`graph_gradients`]): the same MSE, sample counts, MLP and
//! appearance gradients, and table gradient, on the same rays, depths and backgrounds.

use std::collections::BTreeMap;
use std::sync::Arc;

use candle_core::{Device, Tensor};
use rand::SeedableRng;

use crate::model::TrainModel;
use crate::step::{
    fused_gradients, fused_step_applies, graph_gradients, step_background, StepGradients,
    StepSettings, TrainRng,
};
use nerf_core::contraction::Contraction;
use nerf_core::rays::Rays;
use nerf_field::ngp::{small_test_params, DensityActivation, NgpParams, NgpState, TABLE};
use nerf_field::trainable::named_vars;
use nerf_hash_grid::hash_grid::{HashGridParams, TableGradient};
use nerf_kernels::test_support::uniform_values;
use nerf_render::occupancy::{OccupancyGrid, OccupancyGridParams};
use nerf_render::ray_sampler::RaySampler;
use nerf_render::renderer::VolumeRenderer;
use nerf_render::sampler::StratifiedSampler;

/// A small model of `params` with a table of U(−1, 1) values (so that densities and colours
/// vary), its sink, and a grid with the cells of a ball of radius 1 occupied.
fn model(params: &NgpParams, seed: u64) -> (TrainModel, Arc<TableGradient>) {
    let dev = Device::Cpu;
    let state = NgpState::seeded(params, seed, &dev).unwrap();
    let sink = state.gradient.clone();
    let table = named_vars(&state.varmap)
        .into_iter()
        .find(|(name, _)| name == TABLE)
        .unwrap()
        .1;
    let values = uniform_values(table.elem_count(), seed, -1f32, 1.0);
    table
        .set(&Tensor::from_vec(values, table.shape(), &dev).unwrap())
        .unwrap();
    let mut model = TrainModel::new(Box::new(state));
    let half = params.aabb[1][0];
    let mut grid = OccupancyGrid::new(&OccupancyGridParams {
        resolution: 8,
        aabb: [-half, -half, -half, half, half, half],
        contraction: params.contraction,
        ..OccupancyGridParams::default()
    })
    .unwrap();
    let r = grid.resolution;
    for (k, occupied) in grid.occupied.iter_mut().enumerate() {
        let cell = [k / (r * r), (k / r) % r, k % r];
        let centre = cell.map(|c| (c as f64 + 0.5) / r as f64 * 2.0 * half - half);
        *occupied = centre.iter().map(|c| c * c).sum::<f64>() < 1.0;
    }
    model.occupancy = Some(grid);
    (model, sink)
}

/// `n` rays from a sphere of radius 4 towards points in `[−0.8, 0.8]³`, from training
/// images 0..3.
fn rays(n: usize, seed: u64) -> Rays {
    let dev = Device::Cpu;
    let u = uniform_values(6 * n, seed, -1f32, 1.0);
    let mut origins = Vec::new();
    let mut directions = Vec::new();
    for r in u.chunks_exact(6) {
        let len = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt().max(1e-3);
        let o = [r[0], r[1], r[2]].map(|v| 4.0 * v / len);
        let d: [f32; 3] = std::array::from_fn(|k| 0.8 * r[3 + k] - o[k]);
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        origins.extend(o);
        directions.extend(d.map(|v| v / len));
    }
    let cameras: Vec<u32> = (0..n as u32).map(|i| i % 3).collect();
    Rays {
        origins: Tensor::from_vec(origins, (n, 3), &dev).unwrap(),
        directions: Tensor::from_vec(directions, (n, 3), &dev).unwrap(),
        camera_index: Some(Tensor::from_vec(cameras, n, &dev).unwrap()),
    }
}

fn settings(random_background: bool, early_termination: f64) -> StepSettings {
    let sampler: Arc<dyn RaySampler> = Arc::new(StratifiedSampler::new(48, 2.0, 6.0).unwrap());
    StepSettings {
        batch_size: 0,
        rays_from_all_images: true,
        random_background,
        density_noise: 0.0,
        sampler,
        renderer: VolumeRenderer::new(1 << 16, false)
            .unwrap()
            .with_background([0.2, 0.5, 0.9])
            .with_early_termination(early_termination)
            .unwrap(),
        distortion_loss: 0.0,
    }
}

/// The table gradient left in `sink`, by row.
fn table_gradient(sink: &TableGradient, grid: &HashGridParams) -> BTreeMap<u32, Vec<f32>> {
    let f = grid.n_features;
    sink.take(grid, |rows, values| {
        rows.iter()
            .map(|&r| (r, values[r as usize * f..(r as usize + 1) * f].to_vec()))
            .collect()
    })
}

/// Every trained variable's gradient in `step`, by name.
fn gradients(model: &TrainModel, step: &StepGradients) -> BTreeMap<String, Vec<f32>> {
    named_vars(model.varmap())
        .into_iter()
        .filter_map(|(name, var)| {
            let g = step.grads.get(var.as_tensor())?;
            Some((name, g.flatten_all().unwrap().to_vec1::<f32>().unwrap()))
        })
        .collect()
}

/// Asserts `a` within `tol` of `b`, relative to `b`'s largest magnitude (which must not be 0).
fn assert_near(a: &[f32], b: &[f32], tol: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "{what}: an all-zero gradient");
    let diff = a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    assert!(
        diff <= tol * scale,
        "{what}: differs by {diff} (scale {scale})"
    );
}

#[test]
fn fused_step_matches_the_autograd_step() {
    let cases = [
        (
            "bounded, random background",
            small_test_params(),
            true,
            1e-2,
        ),
        (
            "contracted, appearance, softplus, dataset background, no termination",
            NgpParams {
                aabb: [[-2.0; 3], [2.0; 3]],
                contraction: Contraction::LInf,
                appearance_dim: 4,
                appearance_images: 3,
                density_activation: DensityActivation::Softplus,
                ..small_test_params()
            },
            false,
            0.0,
        ),
    ];
    for (what, params, random_background, termination) in cases {
        let (model, sink) = model(&params, 3);
        let settings = settings(random_background, termination);
        let rays = rays(300, 11);
        let target =
            Tensor::from_vec(uniform_values(900, 5, 0f32, 1.0), (300, 3), &Device::Cpu).unwrap();
        let transparency =
            Tensor::from_vec(uniform_values(300, 6, 0f32, 1.0), (300, 1), &Device::Cpu).unwrap();
        let field = model.training_field(0.0);
        assert!(fused_step_applies(&settings, &*field), "{what}");
        let mut rng = TrainRng::seed_from_u64(9);
        let background = step_background(&settings, &target, &transparency, &mut rng).unwrap();
        let (mut rng_graph, mut rng_fused) = (rng.clone(), rng);
        let graph =
            graph_gradients(&*field, &settings, &rays, &background, &mut rng_graph).unwrap();
        let graph_table = table_gradient(&sink, &params.grid());
        let fused = fused_gradients(
            &model,
            &settings,
            &*field,
            &rays,
            &background,
            &mut rng_fused,
        )
        .unwrap()
        .expect("the hash-grid field has a fused step");
        let fused_table = table_gradient(&sink, &params.grid());

        assert_eq!(fused.samples, graph.samples, "{what}: sample counts");
        assert!(
            fused.samples.evaluated > 1000,
            "{what}: {:?}",
            fused.samples
        );
        assert!(
            fused.samples.evaluated < fused.samples.total,
            "{what}: some samples skipped"
        );
        let rel = (fused.mse / graph.mse - 1.0).abs();
        assert!(
            rel < 1e-5,
            "{what}: MSE {} against {}",
            fused.mse,
            graph.mse
        );
        let (g, f) = (gradients(&model, &graph), gradients(&model, &fused));
        let names: Vec<&String> = g.keys().collect();
        assert_eq!(
            names,
            f.keys().collect::<Vec<_>>(),
            "{what}: the same variables"
        );
        let expected = 10 + if params.appearance_dim > 0 { 2 } else { 0 };
        assert_eq!(names.len(), expected, "{what}: {names:?}");
        for (name, want) in &g {
            assert_near(&f[name], want, 1e-4, &format!("{what}: {name}"));
        }
        let rows: Vec<&u32> = graph_table.keys().collect();
        assert_eq!(rows, fused_table.keys().collect::<Vec<_>>(), "{what}: rows");
        let flat = |t: &BTreeMap<u32, Vec<f32>>| t.values().flatten().copied().collect::<Vec<_>>();
        assert_near(&flat(&fused_table), &flat(&graph_table), 1e-4, what);
    }
}
