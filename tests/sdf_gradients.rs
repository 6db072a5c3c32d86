//! Gradients of a rendered SDF volume with respect to every parameter, against central finite
//! differences computed in float64.
//!
//! The loss is `Σ r ⊙ colour` over a small image with fixed random weights `r`, rendered
//! through the sampler and the volume renderer. Finite differences perturb each parameter
//! component by ±h in a float64 render (the generic tensor ops: float64 never takes the fused
//! kernels). Against them:
//! * float64 autograd through the generic path (the maths of the tensor-op backward passes);
//! * float32 autograd through the fused CPU kernels (the default) and through the generic
//!   path (`--kernels generic`), within float32 precision.

use candle_core::{DType, Device, Tensor, Var};
use glam::DVec3;
use nerf::kernels::sdf_volume::{SdfTensors, ShapeTensors};
use nerf::{
    look_at_view_transform, with_kernel_choice, KernelChoice, PerspectiveCamera, Rays, SdfField,
    StratifiedSampler, VolumeRenderer,
};

/// Parameter values by name, in the packed order.
type Params = Vec<(&'static str, Vec<f64>)>;

fn box_params() -> Params {
    vec![
        ("center", vec![0.1, -0.05, 0.15]),
        ("side_lengths", vec![1.3, 1.0, 1.6]),
        ("alpha", vec![0.95]),
        ("beta", vec![0.08]),
        ("feature", vec![0.9, 0.7, 1.0]),
    ]
}

fn sphere_params() -> Params {
    vec![
        ("center", vec![-0.1, 0.1, 0.05]),
        ("radius", vec![0.9]),
        ("alpha", vec![0.8]),
        ("beta", vec![0.1]),
        ("feature", vec![0.6, 0.9, 0.8]),
    ]
}

/// The field with every parameter a variable of `dtype`, and the variables in order.
fn field(params: &Params, rainbow: bool, dtype: DType) -> (SdfField, Vec<Var>) {
    let vars: Vec<Var> = params
        .iter()
        .map(|(_, v)| {
            Var::from_tensor(
                &Tensor::new(v.as_slice(), &Device::Cpu)
                    .unwrap()
                    .to_dtype(dtype)
                    .unwrap(),
            )
            .unwrap()
        })
        .collect();
    let t = |i: usize| vars[i].as_tensor().clone();
    let shape = if params[1].0 == "side_lengths" {
        ShapeTensors::Box {
            center: t(0),
            side_lengths: t(1),
        }
    } else {
        ShapeTensors::Sphere {
            center: t(0),
            radius: t(1),
        }
    };
    let field = SdfField {
        params: SdfTensors {
            shape,
            alpha: t(2),
            beta: t(3),
            rainbow,
            feature: t(4),
        },
        variables: params
            .iter()
            .zip(&vars)
            .map(|((n, _), v)| (n.to_string(), v.clone()))
            .collect(),
    };
    (field, vars)
}

struct Setup {
    rays: Rays,
    weights: Tensor,
    sampler: StratifiedSampler,
    renderer: VolumeRenderer,
}

fn setup() -> Setup {
    let (r, t) = look_at_view_transform(
        DVec3::new(-1.8, 0.7, -2.2),
        DVec3::new(0.05, 0.0, 0.0),
        DVec3::Y,
    );
    let mut camera = PerspectiveCamera::new(r, t, 1.1);
    camera.principal_point = [0.05, -0.03];
    let (w, h) = (14, 11);
    let rays = Rays::for_image(&nerf::Camera::from(camera), w, h, &Device::Cpu).unwrap();
    let weights: Vec<f64> = {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        (0..w * h * 3)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect()
    };
    let weights = Tensor::from_vec(weights, (w * h, 3), &Device::Cpu).unwrap();
    Setup {
        rays,
        weights,
        sampler: StratifiedSampler::new(40, 0.5, 5.0).unwrap(),
        renderer: VolumeRenderer::new(4096, false).unwrap(),
    }
}

/// `Σ r ⊙ colour` of the render, in the field's dtype.
fn loss(setup: &Setup, field: &SdfField, dtype: DType) -> Tensor {
    let rays = setup.rays.to_dtype(dtype).unwrap();
    let out = setup
        .renderer
        .render(field, &setup.sampler, &rays, None)
        .unwrap();
    out.color
        .mul(&setup.weights.to_dtype(dtype).unwrap())
        .unwrap()
        .sum_all()
        .unwrap()
}

/// Central differences in float64, one per parameter component, step `h`.
fn finite_differences(setup: &Setup, params: &Params, rainbow: bool, h: f64) -> Vec<Vec<f64>> {
    let value = |p: &Params| {
        let (f, _) = field(p, rainbow, DType::F64);
        loss(setup, &f, DType::F64).to_scalar::<f64>().unwrap()
    };
    params
        .iter()
        .enumerate()
        .map(|(i, (_, v))| {
            (0..v.len())
                .map(|k| {
                    let mut plus = params.clone();
                    plus[i].1[k] += h;
                    let mut minus = params.clone();
                    minus[i].1[k] -= h;
                    (value(&plus) - value(&minus)) / (2.0 * h)
                })
                .collect()
        })
        .collect()
}

/// Autograd gradients of every parameter, as float64.
fn autograd(setup: &Setup, params: &Params, rainbow: bool, dtype: DType) -> Vec<Vec<f64>> {
    let (f, vars) = field(params, rainbow, dtype);
    let grads = loss(setup, &f, dtype).backward().unwrap();
    vars.iter()
        .map(|v| {
            grads
                .get(v.as_tensor())
                .expect("every parameter gets a gradient")
                .to_dtype(DType::F64)
                .unwrap()
                .to_vec1::<f64>()
                .unwrap()
        })
        .collect()
}

/// Largest error of `got` against `expected` over all components, relative to the largest
/// expected magnitude of its parameter (at least 1e-3, so that near-zero gradients are
/// compared absolutely).
fn worst_relative_error(params: &Params, got: &[Vec<f64>], expected: &[Vec<f64>]) -> f64 {
    let mut worst = 0f64;
    for (i, (name, _)) in params.iter().enumerate() {
        let scale = expected[i].iter().fold(1e-3f64, |m, v| m.max(v.abs()));
        for (k, (g, e)) in got[i].iter().zip(&expected[i]).enumerate() {
            let err = (g - e).abs() / scale;
            assert!(g.is_finite(), "{name}[{k}]: gradient {g}");
            if err > worst {
                worst = err;
            }
            eprintln!("{name}[{k}]: autograd {g:+.6e} finite difference {e:+.6e}");
        }
    }
    worst
}

fn check(params: Params, rainbow: bool) {
    let setup = setup();
    let fd = finite_differences(&setup, &params, rainbow, 1e-6);
    // Every parameter matters to this image.
    for (i, (name, _)) in params.iter().enumerate() {
        assert!(
            fd[i].iter().any(|v| v.abs() > 1e-3),
            "{name}: the image does not depend on it"
        );
    }
    let f64_err = worst_relative_error(
        &params,
        &autograd(&setup, &params, rainbow, DType::F64),
        &fd,
    );
    let fused = with_kernel_choice(KernelChoice::Fused, || {
        autograd(&setup, &params, rainbow, DType::F32)
    });
    let fused_err = worst_relative_error(&params, &fused, &fd);
    let generic = with_kernel_choice(KernelChoice::Generic, || {
        autograd(&setup, &params, rainbow, DType::F32)
    });
    let generic_err = worst_relative_error(&params, &generic, &fd);
    eprintln!(
        "worst relative error: float64 autograd {f64_err:.1e}, float32 fused {fused_err:.1e}, float32 generic {generic_err:.1e}"
    );
    assert!(
        f64_err < 1e-6,
        "float64 autograd vs finite differences: {f64_err}"
    );
    assert!(
        fused_err < 2e-4,
        "fused float32 autograd vs finite differences: {fused_err}"
    );
    assert!(
        generic_err < 2e-4,
        "generic float32 autograd vs finite differences: {generic_err}"
    );
}

#[test]
fn box_gradients_match_float64_finite_differences() {
    check(box_params(), true);
}

#[test]
fn sphere_gradients_match_float64_finite_differences() {
    check(sphere_params(), false);
}

#[test]
fn rainbow_sphere_gradients_match_float64_finite_differences() {
    check(sphere_params(), true);
}

/// The training step's fused render-and-loss kernel (`sdf_render_mse`, used by the box fit)
/// against its twin, the renderer and tensor ops: the same loss and gradients, on black and
/// on white.
#[test]
fn fused_training_loss_matches_renderer_and_tensor_ops() {
    use nerf::train::fit_sdf::{batch_loss, SdfFitSettings};
    let setup = setup();
    let target = Tensor::rand(0f32, 1.0, (setup.rays.len(), 3), &Device::Cpu).unwrap();
    for (params, rainbow) in [(box_params(), true), (sphere_params(), false)] {
        for white in [false, true] {
            let settings = SdfFitSettings {
                num_epochs: 1,
                batch_size: setup.rays.len(),
                lr: 1e-3,
                seed: 0,
                sampler: setup.sampler,
                renderer: VolumeRenderer::new(4096, white).unwrap(),
            };
            let run = |choice| {
                with_kernel_choice(choice, || {
                    let (f, vars) = field(&params, rainbow, DType::F32);
                    let model = nerf::field::sdf::SdfModel::from_field(f);
                    let loss = batch_loss(&model, &settings, &setup.rays, &target).unwrap();
                    let grads = loss.backward().unwrap();
                    let g: Vec<Vec<f32>> = vars
                        .iter()
                        .map(|v| grads.get(v.as_tensor()).unwrap().to_vec1::<f32>().unwrap())
                        .collect();
                    (loss.to_scalar::<f32>().unwrap(), g)
                })
            };
            let (fused_loss, fused) = run(KernelChoice::Fused);
            let (generic_loss, generic) = run(KernelChoice::Generic);
            assert!(
                (fused_loss - generic_loss).abs() <= 1e-5 * generic_loss,
                "loss {fused_loss} vs {generic_loss}"
            );
            for ((a, b), (name, _)) in fused.iter().zip(&generic).zip(&params) {
                let scale = b.iter().fold(1e-3f32, |m, v| m.max(v.abs()));
                for (x, y) in a.iter().zip(b) {
                    assert!(
                        (x - y).abs() <= 1e-3 * scale,
                        "{name} (white {white}): {x} vs {y}"
                    );
                }
            }
        }
    }
}
