//! The skipping pass (`render::skipping`) on a NeRF field: packed evaluation, occupancy
//! grids and early termination against the dense path.

use std::sync::Arc;

use candle_core::Device;

use crate::nerf::{Nerf, NerfField, NerfParams};
use candle_core::Tensor;
use nerf_core::contraction::Contraction;
use nerf_core::rays::Rays;
use nerf_kernels::composite::composite;
use nerf_kernels::composite::Composited;
use nerf_kernels::sample_points::sample_points;
use nerf_render::field::Field;
use nerf_render::field::FieldOutput;
use nerf_render::occupancy::{OccupancyGrid, OccupancyGridParams};
use nerf_render::occupied_field::OccupiedField;
use nerf_render::renderer::{RenderOutput, VolumeRenderer};
use nerf_render::sampler::{RaySamples, StratifiedSampler};
use nerf_render::skipping::*;

/// A small NeRF whose density bias is `density_bias` (large values make rays terminate).
fn model(density_bias: f32) -> Nerf {
    let cfg = NerfParams {
        n_harmonic_functions_xyz: 4,
        n_harmonic_functions_dir: 2,
        n_hidden_neurons_xyz: 32,
        n_hidden_neurons_dir: 16,
        n_layers_xyz: 3,
        append_xyz: vec![2],
        density_noise_std: 0.0,
    };
    // Seeded, so every run tests the same weights.
    let state = crate::nerf::NerfState::seeded(&cfg, 3, &Device::Cpu).unwrap();
    state.varmap.data().lock().unwrap()["density_layer.0.bias"]
        .set(&Tensor::new(&[density_bias], &Device::Cpu).unwrap())
        .unwrap();
    state.model
}

fn rays() -> Rays {
    let cam = nerf_core::camera::surround_cameras(4.0, 3, glam::DVec3::Z, 2.0)[1];
    Rays::for_image(&nerf_core::camera::Camera::from(cam), 9, 7, &Device::Cpu).unwrap()
}

fn render(
    renderer: VolumeRenderer,
    field: &dyn Field,
    sampler: &StratifiedSampler,
) -> RenderOutput {
    renderer.render(field, sampler, &rays(), None).unwrap()
}

fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
    nerf_core::compare::max_abs_difference(a, b).unwrap()
}

/// The NeRF `model` as a field, rendered through `grid` when given.
fn field(model: &Nerf, grid: Option<OccupancyGrid>) -> Box<dyn Field> {
    let field = NerfField {
        model: model.clone(),
        density_noise: 0.0,
    };
    match grid {
        Some(grid) => Box::new(OccupiedField {
            field: Box::new(field),
            grid: Arc::new(grid),
        }),
        None => Box::new(field),
    }
}

#[test]
fn a_chunk_of_skipping_rays_draws_a_bounded_number_of_samples() {
    let m = model(0.0);
    let f = field(&m, None);
    let renderer = VolumeRenderer::new(1 << 20, false)
        .unwrap()
        .with_early_termination(1e-3)
        .unwrap();
    let per_segment = f
        .fast_paths()
        .expect("a NeRF's fast paths")
        .max_samples_per_chunk()
        / SEGMENT;
    for s in [16, 128, 1024, 4096, 16384] {
        let sampler = StratifiedSampler::new(s, 0.1, 6.0).unwrap();
        let rays = renderer.rays_per_chunk(&*f, &sampler);
        assert!(
            rays * s <= nerf_render::renderer::DRAWN_SAMPLES_PER_CHUNK,
            "S = {s}"
        );
        assert!(rays <= per_segment, "S = {s}");
        // Normal sizes keep the chunk the evaluated samples allow; only long rays shrink it
        // (over 1024 samples a ray for a NeRF's 2^17-sample chunk, 8192 rays of 16-sample
        // segments, at 2^23 drawn samples a chunk).
        let long = s * per_segment > nerf_render::renderer::DRAWN_SAMPLES_PER_CHUNK;
        assert_eq!(rays == per_segment, !long, "S = {s}: {rays} rays");
        assert_eq!(long, s > 1024);
    }
}

/// An all-occupied grid of `resolution`³ cells over the cube `±half_side` (density
/// threshold 1).
fn grid(resolution: usize, half_side: f64, contraction: Contraction) -> OccupancyGrid {
    let h = half_side;
    let config = OccupancyGridParams {
        resolution,
        aabb: [-h, -h, -h, h, h, h],
        density_threshold: 1.0,
        contraction,
    };
    OccupancyGrid::new(&config).unwrap()
}

/// An all-occupied grid large enough to hold every sample of the tests' rays.
fn all_occupied_grid() -> OccupancyGrid {
    grid(64, 10.0, Contraction::None)
}

/// A 4³ grid over ±1 with cell `c` empty where `c % every == empty`.
fn striped_grid(every: usize, empty: usize) -> OccupancyGrid {
    let mut grid = grid(4, 1.0, Contraction::None);
    for (c, o) in grid.occupied.iter_mut().enumerate() {
        *o = c % every != empty;
    }
    grid
}

#[test]
fn packed_forward_equals_dense_forward() {
    let m = model(0.1);
    let points = Tensor::randn(0f32, 1.0, (4, 5, 3), &Device::Cpu).unwrap();
    let dirs = Tensor::randn(0f32, 1.0, (4, 3), &Device::Cpu).unwrap();
    let dense = m.forward(&points, &dirs, 0.0).unwrap();
    let index: Vec<u32> = vec![0, 3, 7, 8, 19];
    let idx = Tensor::new(index.as_slice(), &Device::Cpu).unwrap();
    let ray_index: Vec<u32> = index.iter().map(|k| k / 5).collect();
    let (density, colour) = m
        .forward_packed(
            &points
                .reshape((20, 3))
                .unwrap()
                .index_select(&idx, 0)
                .unwrap(),
            &Tensor::new(ray_index.as_slice(), &Device::Cpu).unwrap(),
            &dirs,
            0.0,
        )
        .unwrap();
    let pick = |t: &Tensor, c: usize| t.reshape((20, c)).unwrap().index_select(&idx, 0).unwrap();
    assert!(max_diff(&density, &pick(&dense.density, 1)) < 1e-6);
    assert!(max_diff(&colour, &pick(&dense.feature, 3)) < 1e-6);
}

#[test]
fn all_occupied_grid_without_termination_is_dense_rendering() {
    let m = model(0.3);
    let sampler = StratifiedSampler::new(24, 2.0, 6.0).unwrap();
    let grid = all_occupied_grid();
    let renderer = VolumeRenderer::new(1000, false).unwrap();
    let dense = render(renderer, &*field(&m, None), &sampler);
    let skipped = render(renderer, &*field(&m, Some(grid)), &sampler);
    assert_eq!(skipped.samples.evaluated, skipped.samples.total);
    assert!(max_diff(&dense.color, &skipped.color) < 1e-6);
    assert!(max_diff(&dense.depth, &skipped.depth) < 1e-5);
}

#[test]
fn early_termination_error_is_bounded_by_its_threshold() {
    // Dense enough that most rays become opaque inside the aabb.
    let m = model(8.0);
    let sampler = StratifiedSampler::new(64, 2.0, 6.0).unwrap();
    let dense = render(
        VolumeRenderer::new(1000, false).unwrap(),
        &*field(&m, None),
        &sampler,
    );
    for threshold in [1e-2, 1e-4] {
        let renderer = VolumeRenderer::new(1000, false)
            .unwrap()
            .with_early_termination(threshold)
            .unwrap();
        let out = render(renderer, &*field(&m, None), &sampler);
        // Every ray turns opaque within its first 16 samples, so it stops by the end of
        // the fourth segment (4 + 4 + 8 + 16 of its 64 samples).
        assert!(
            out.samples.evaluated <= out.samples.total / 2,
            "{:?}",
            out.samples
        );
        // Dropped weights sum to at most the transmittance at termination.
        let colour_error = max_diff(&dense.color, &out.color);
        assert!(colour_error <= threshold as f32 * 1.001, "{colour_error}");
        let depth_error = max_diff(&dense.depth, &out.depth);
        assert!(
            depth_error <= 6.0 * threshold as f32 * 1.001,
            "{depth_error}"
        );
    }
}

#[test]
fn empty_cells_render_as_zero_density() {
    let m = model(1.0);
    let sampler = StratifiedSampler::new(32, 2.0, 6.0).unwrap();
    let grid = striped_grid(3, 0);
    let renderer = VolumeRenderer::new(1000, false).unwrap();
    let out = render(renderer, &*field(&m, Some(grid.clone())), &sampler);
    assert!(out.samples.evaluated < out.samples.total);
    // Independent recomputation: dense field, density zeroed outside occupied cells.
    let samples = sampler.sample(&rays(), None).unwrap();
    let (dense, density) = dense_and_masked(&m, &grid, &samples);
    let Composited { color, depth, .. } =
        composite(&density, &dense.feature, &samples.lengths).unwrap();
    assert!(max_diff(&color, &out.color) < 1e-6);
    assert!(max_diff(&depth, &out.depth) < 1e-5);
}

/// The dense field of `m` at `samples` of [`rays`], and its density zeroed outside `grid`'s
/// occupied cells (the skipping pass's result, recomputed independently).
fn dense_and_masked(m: &Nerf, grid: &OccupancyGrid, samples: &RaySamples) -> (FieldOutput, Tensor) {
    let dense = m.forward(&samples.points, &rays().directions, 0.0).unwrap();
    let points = samples
        .points
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    let mask: Vec<f32> = points
        .chunks_exact(3)
        .map(|p| f32::from(u8::from(grid.is_occupied([p[0], p[1], p[2]]))))
        .collect();
    let mask = Tensor::from_vec(mask, samples.lengths.shape(), &Device::Cpu).unwrap();
    let masked = dense.density.mul(&mask).unwrap();
    (dense, masked)
}

/// Every one of the rays' `n` samples per ray materialised and tested against `grid` on its
/// own: the samples' points `(R·n·3)` flattened, and the indices (ray-major) of those in
/// occupied cells. `lengths` is `(1, n, 1)` or `(R, n, 1)`.
fn occupied_samples(
    grid: &OccupancyGrid,
    rays: &Rays,
    lengths: &Tensor,
    n: usize,
) -> (Vec<f32>, Vec<u32>) {
    let dense_lengths = lengths.broadcast_as((rays.len(), n, 1)).unwrap();
    let points = sample_points(&rays.origins, &rays.directions, &dense_lengths)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    let occupied = (0..points.len() / 3)
        .filter(|&k| grid.is_occupied([points[3 * k], points[3 * k + 1], points[3 * k + 2]]))
        .map(|k| k as u32)
        .collect();
    (points, occupied)
}

#[test]
fn marching_keeps_exactly_the_samples_in_occupied_cells() {
    use rand::{Rng, SeedableRng};
    // A 32³ grid over ±1.5 (4³ blocks): occupied cells scattered inside a ball, so most
    // blocks are empty and whole blocks are skipped.
    let mut grid = grid(32, 1.5, Contraction::None);
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    for (c, o) in grid.occupied.iter_mut().enumerate() {
        let [x, y, z] = [c / 1024, (c / 32) % 32, c % 32].map(|v| v as f32 - 15.5);
        *o = x * x + y * y + z * z < 100.0 && rng.random::<f32>() < 0.3;
    }
    let cam = nerf_core::camera::surround_cameras(4.0, 3, glam::DVec3::Z, 2.0)[1];
    let rays =
        Rays::for_image(&nerf_core::camera::Camera::from(cam), 24, 20, &Device::Cpu).unwrap();
    let sampler = StratifiedSampler::new(96, 2.0, 6.0).unwrap();
    let check = |packed: &PackedSamples, _: &[f32], expected: &[u32]| {
        assert!(!expected.is_empty());
        assert!(
            packed.counts.examined < packed.counts.total / 2,
            "{:?}",
            packed.counts
        );
    };
    assert_marching_keeps_the_occupied_samples(&grid, &rays, &sampler, &mut rng, check);
}

#[test]
fn cell_by_cell_marching_keeps_exactly_the_samples_of_grazing_and_face_parallel_rays() {
    use rand::{Rng, SeedableRng};
    // Half the cells occupied at random, so nearly every cell crossed changes the answer,
    // and some blocks empty; rays along cell faces (origins on a face plane, directions in
    // it or a hair off it), along the axes, and at random, with 512 samples so that several
    // share each cell.
    let mut grid = grid(16, 1.5, Contraction::None);
    let mut rng = rand::rngs::StdRng::seed_from_u64(21);
    for (c, o) in grid.occupied.iter_mut().enumerate() {
        *o = c / 256 >= 8 && rng.random::<f32>() < 0.5;
    }
    let face = -1.5 + 5.0 * 3.0 / 16.0;
    let mut origins: Vec<f32> = Vec::new();
    let mut directions: Vec<f32> = Vec::new();
    let mut ray = |o: [f64; 3], d: [f64; 3]| {
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        origins.extend(o.map(|v| v as f32));
        directions.extend(d.map(|v| (v / n) as f32));
    };
    for tilt in [0.0, 1e-7, -1e-7, 1e-4, 1e-2] {
        ray([-4.0, face, 0.1], [1.0, tilt, 0.0]);
        ray([0.2, -4.0, face], [tilt, 1.0, -tilt]);
        ray([face, face, 4.0], [tilt, 0.0, -1.0]);
        ray([4.0, 0.3, face], [-1.0, tilt, tilt]);
    }
    for _ in 0..200 {
        let o = std::array::from_fn(|_| rng.random_range(-4.0..4.0));
        let target: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.5..1.5));
        ray(o, std::array::from_fn(|k| target[k] - o[k]));
    }
    let n = origins.len() / 3;
    let rays = Rays::new(
        Tensor::from_vec(origins, (n, 3), &Device::Cpu).unwrap(),
        Tensor::from_vec(directions, (n, 3), &Device::Cpu).unwrap(),
    );
    let sampler = StratifiedSampler::new(512, 0.5, 9.0).unwrap();
    let check = |packed: &PackedSamples, _: &[f32], expected: &[u32]| {
        assert!(expected.len() > 1000, "{}", expected.len());
        // Far fewer lookups than samples in the box: one or two per cell crossed.
        assert!(
            packed.counts.examined < expected.len(),
            "{:?}",
            packed.counts
        );
    };
    assert_marching_keeps_the_occupied_samples(&grid, &rays, &sampler, &mut rng, check);
}

/// Asserts that `grid` has empty blocks and that marching `rays` at `sampler`'s depths through
/// a field with `grid`, unjittered and then jittered by `rng`, keeps exactly the samples in
/// occupied cells, every sample materialised and tested on its own ([`occupied_samples`]);
/// `check` first sees each packed pass, the samples' points and the indices of the occupied
/// ones.
fn assert_marching_keeps_the_occupied_samples(
    grid: &OccupancyGrid,
    rays: &Rays,
    sampler: &StratifiedSampler,
    rng: &mut rand::rngs::StdRng,
    check: impl Fn(&PackedSamples, &[f32], &[u32]),
) {
    assert!(grid.empty_blocks().empty.iter().any(|e| *e));
    let f = field(&model(1.0).detached(), Some(grid.clone()));
    for jitter in [false, true] {
        let lengths = if jitter {
            sampler.compact_lengths(rays, Some(&mut *rng))
        } else {
            sampler.compact_lengths(rays, None)
        }
        .unwrap();
        let packed = evaluate_packed(&*f, 0.0, rays, &lengths).unwrap();
        let n = sampler.n_pts_per_ray;
        let (points, expected) = occupied_samples(grid, rays, &lengths, n);
        check(&packed, &points, &expected);
        let mut got = packed.index.clone();
        got.sort_unstable();
        assert_eq!(got, expected, "jitter {jitter}");
    }
}

#[test]
fn packed_compositing_equals_the_dense_scatter_bit_for_bit() {
    let m = model(2.0);
    let sampler = StratifiedSampler::new(48, 2.0, 6.0).unwrap();
    let grid = striped_grid(5, 0);
    let f = field(&m.detached(), Some(grid));
    let samples = sampler.sample(&rays(), None).unwrap();
    for termination in [0.0, 1e-2] {
        let packed = evaluate_packed(&*f, termination, &rays(), &samples.lengths).unwrap();
        assert!(!packed.tracks_gradient());
        let (direct, dense) = composited_packed_and_dense(packed, &samples.lengths);
        for (what, a, b) in [
            ("colour", &direct.color, &dense.color),
            ("depth", &direct.depth, &dense.depth),
            ("opacity", &direct.opacity, &dense.opacity),
        ] {
            assert_eq!(max_diff(a, b), 0.0, "{what}, termination {termination}");
        }
    }
}

/// The packed values composited straight ([`PackedSamples::composite`]) and after
/// scattering them into dense tensors ([`composite`]).
fn composited_packed_and_dense(
    packed: PackedSamples,
    lengths: &Tensor,
) -> (Composited, Composited) {
    let direct = packed.composite(lengths).unwrap();
    let dense = packed.scatter(&Device::Cpu).unwrap();
    let dense = composite(&dense.density, &dense.feature, lengths).unwrap();
    (direct, dense)
}

#[test]
fn packed_compositing_gradients_equal_the_dense_paths() {
    let state = {
        let cfg = NerfParams {
            n_harmonic_functions_xyz: 3,
            n_harmonic_functions_dir: 2,
            n_hidden_neurons_xyz: 16,
            n_hidden_neurons_dir: 8,
            n_layers_xyz: 2,
            append_xyz: vec![1],
            density_noise_std: 0.0,
        };
        crate::nerf::NerfState::seeded(&cfg, 5, &Device::Cpu).unwrap()
    };
    let sampler = StratifiedSampler::new(32, 2.0, 6.0).unwrap();
    let grid = striped_grid(4, 1);
    let f = field(&state.model, Some(grid));
    let samples = sampler.sample(&rays(), None).unwrap();
    let packed = evaluate_packed(&*f, 1e-3, &rays(), &samples.lengths).unwrap();
    assert!(packed.tracks_gradient());
    let (direct, dense) = composited_packed_and_dense(packed, &samples.lengths);
    let weight = Tensor::randn(0f32, 1.0, direct.color.shape(), &Device::Cpu).unwrap();
    let loss = |out: &Composited| {
        let l = (out.color.mul(&weight).unwrap().sum_all().unwrap()
            + out.depth.sum_all().unwrap().affine(0.1, 0.0).unwrap())
        .unwrap();
        (l + out.opacity.sum_all().unwrap())
            .unwrap()
            .backward()
            .unwrap()
    };
    let (ga, gb) = (loss(&direct), loss(&dense));
    for (name, var) in crate::trainable::named_vars(&state.varmap) {
        let (a, b) = (ga.get(&var).unwrap(), gb.get(&var).unwrap());
        nerf_core::compare::assert_close(a, b, 1e-5, &name);
    }
}

#[test]
fn marching_a_contracted_grid_keeps_exactly_the_samples_in_occupied_cells() {
    use rand::{Rng, SeedableRng};
    // A 64³ grid over the contracted cube [-2, 2]³ (blocks of 8 cells: 0.5 wide), occupied
    // cells scattered over a shell and the centre, so that whole empty blocks inside the unit
    // cube are skipped and samples far out (up to 100 units) land in the shell.
    let mut grid = grid(64, 2.0, Contraction::LInf);
    let mut rng = rand::rngs::StdRng::seed_from_u64(12);
    for (c, o) in grid.occupied.iter_mut().enumerate() {
        let [x, y, z] = [c / 4096, (c / 64) % 64, c % 64].map(|v| (v as f32 - 31.5).abs());
        let norm = x.max(y).max(z);
        *o = !(3.0..=24.0).contains(&norm) && rng.random::<f32>() < 0.3;
    }
    // A camera inside the unit cube, as a normalised capture's.
    let cam = nerf_core::camera::surround_cameras(0.9, 3, glam::DVec3::Z, 0.5)[1];
    let rays =
        Rays::for_image(&nerf_core::camera::Camera::from(cam), 16, 12, &Device::Cpu).unwrap();
    let sampler = StratifiedSampler::new(256, 0.02, 100.0).unwrap();
    let check = |packed: &PackedSamples, points: &[f32], expected: &[u32]| {
        // Samples in the shell (far from the unit cube) are among them.
        assert!(expected.iter().any(|&k| {
            let p = &points[3 * k as usize..3 * k as usize + 3];
            p.iter().fold(0f32, |m, v| m.max(v.abs())) > 5.0
        }));
        // Whole blocks inside the unit cube were passed over without a test.
        assert!(
            packed.counts.examined < packed.counts.total,
            "{:?}",
            packed.counts
        );
    };
    assert_marching_keeps_the_occupied_samples(&grid, &rays, &sampler, &mut rng, check);
}

#[test]
fn distortion_loss_of_the_packed_and_dense_paths_equals_its_recomputation() {
    use nerf_kernels::distortion_loss::distortion_loss_tensor_ops;
    use nerf_render::ray_sampler::RaySampler;
    let m = model(1.0);
    let sampler = StratifiedSampler::new(32, 2.0, 6.0).unwrap();
    let spacing = RaySampler::spacing(&sampler).unwrap();
    let grid = striped_grid(3, 0);
    let mut renderer = VolumeRenderer::new(1000, false).unwrap();
    renderer.distortion_loss = true;
    // Dense, then packed through the grid (its empty cells as zero density).
    let dense_out = render(renderer, &*field(&m, None), &sampler);
    let packed_out = render(renderer, &*field(&m, Some(grid.clone())), &sampler);
    assert!(packed_out.samples.evaluated < packed_out.samples.total);
    let samples = sampler.sample(&rays(), None).unwrap();
    let (dense, masked) = dense_and_masked(&m, &grid, &samples);
    for (out, density) in [(&dense_out, &dense.density), (&packed_out, &masked)] {
        let want = distortion_loss_tensor_ops(density, &samples.lengths, spacing).unwrap();
        let got = out.distortion.as_ref().expect("a distortion loss");
        assert_eq!(got.dims(), &[rays().len(), 1]);
        assert!(max_diff(got, &want) < 1e-5, "{}", max_diff(got, &want));
    }
    // Off unless asked for.
    renderer.distortion_loss = false;
    assert!(render(renderer, &*field(&m, None), &sampler)
        .distortion
        .is_none());
}

#[test]
fn tracked_rays_get_the_dense_paths_gradient_through_the_packed_pass() {
    // Every sample evaluated (an all-occupied grid, no termination): the packed pass with
    // its points formed as tensor ops must give the rays the dense path's gradient, and the
    // values of the packed pass of untracked rays.
    let m = model(0.3);
    let sampler = StratifiedSampler::new(24, 2.0, 6.0).unwrap();
    let grid = || Some(all_occupied_grid());
    let renderer = VolumeRenderer::new(1000, false).unwrap();
    let plain = rays();
    let origins = candle_core::Var::from_tensor(&plain.origins).unwrap();
    let directions = candle_core::Var::from_tensor(&plain.directions).unwrap();
    let tracked = Rays {
        origins: origins.as_tensor().clone(),
        directions: directions.as_tensor().clone(),
        camera_index: None,
    };
    let untracked = renderer
        .render(&*field(&m, grid()), &sampler, &plain, None)
        .unwrap();
    let packed = renderer
        .render(&*field(&m, grid()), &sampler, &tracked, None)
        .unwrap();
    // (Not bit for bit: the field's trunk runs as tensor ops on tracked points.)
    assert!(max_diff(&untracked.color, &packed.color) < 1e-6);
    let dense = renderer
        .render(&*field(&m, None), &sampler, &tracked, None)
        .unwrap();
    let weight = Tensor::randn(0f32, 1.0, packed.color.shape(), &Device::Cpu).unwrap();
    let grads = |out: &RenderOutput| {
        let loss = (out.color.mul(&weight).unwrap().sum_all().unwrap()
            + out.depth.sum_all().unwrap().affine(0.1, 0.0).unwrap())
        .unwrap();
        let g = loss.backward().unwrap();
        let get = |v: &candle_core::Var| g.get(v.as_tensor()).expect("a ray gradient").clone();
        (get(&origins), get(&directions))
    };
    let (packed_o, packed_d) = grads(&packed);
    let (dense_o, dense_d) = grads(&dense);
    let size = |t: &Tensor| nerf_core::compare::max_abs_value(t).unwrap();
    assert!(size(&dense_o) > 1e-3 && size(&dense_d) > 1e-3);
    nerf_core::compare::assert_close(&packed_o, &dense_o, 1e-4, "origins");
    nerf_core::compare::assert_close(&packed_d, &dense_d, 1e-4, "directions");
}
