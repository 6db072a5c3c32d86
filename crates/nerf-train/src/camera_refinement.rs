//! Camera refinement: a small rigid correction of each training camera, optimised with the
//! field, for captures whose cameras come from structure from motion and are off by a
//! fraction of a degree or of the scene's size.
//!
//! Each training camera `i` has 6 numbers, zero at the start: a rotation vector `ω_i` (axis
//! times angle, radians) and a translation `t_i` (world units of the normalised frame). Its
//! rays are moved before rendering: the origin (the camera centre) to `o + t_i`, the direction
//! to `R(ω_i)·d`, turned about the camera centre (`so3_exp`). This is nerfstudio's `SO3xR3`
//! camera optimiser: the rotation and translation parametrised apart, both in world axes.
//! Gradients reach the corrections through the rendered points `o + t·d`
//! ([`nerf_render::skipping`] forms them as tensor ops when the rays are tracked, and the
//! hash encoding differentiates its input, `nerf_hash_grid::hash_point_gradient`); the
//! direction's effect on the view-dependent colour (the spherical harmonics of the NGP
//! field) passes no gradient, so the rotation is learnt from where the rays go.
//!
//! The corrections have their own optimiser: Adam (`SparseAdam`, β = (0.9, 0.999), ε =
//! 1e‑15) on the rows of the cameras with rays in the step (a camera without rays in a step
//! keeps its correction and moments), with PyTorch-style weight decay `λ·p` added to the
//! gradient so that the corrections stay small where the photos do not ask for them (a
//! global motion of all cameras is indistinguishable from a motion of the scene; the decay
//! holds it near zero). Its learning rate follows the run's schedule (the same factor of
//! decay as the field's).
//!
//! Held-out cameras are not refined: evaluation renders them as the capture gives them.

use std::collections::HashMap;

use anyhow::{ensure, Context, Result};
use candle_core::backprop::GradStore;
use candle_core::{DType, Device, Tensor, Var};

use crate::sparse_adam::SparseAdam;
use nerf_core::rays::Rays;
use nerf_kernels::sparse_adam::nonzero_rows;
use nerf_scene::dataset::Frame;

/// The checkpoint tensor `(n_cameras, 6)` of the corrections (its optimiser's state is saved
/// as `adam.*.camera_refinement`).
pub(crate) const CHECKPOINT_KEY: &str = "camera_refinement";

/// The corrections' initial learning rate.
pub(crate) const LEARNING_RATE: f64 = 3e-4;

/// The corrections' weight decay `λ` (`λ·p` added to their gradient).
pub(crate) const WEIGHT_DECAY: f64 = 1e-2;

/// The cameras' gradient is taken on every this many steps (the first of each); on the
/// steps between, the rays still move by the current corrections but are not tracked, so
/// the renderer keeps its fast untracked path (a tracked step forms its points as tensor ops
/// and differentiates the hash encoding by its points: docs/own-scene.md#camera-refinement
/// measures the cost).
pub(crate) const GRADIENT_EVERY: u64 = 4;

/// Whether the step after `steps_done` Adam steps takes the cameras' gradient.
pub(crate) fn tracks_cameras(steps_done: u64) -> bool {
    steps_done.is_multiple_of(GRADIENT_EVERY)
}

/// Below this `θ²` the rotation's coefficients are taken from their Taylor series.
const SMALL_ANGLE_SQ: f64 = 1e-8;

/// `training.camera_refinement: auto` refines cameras from structure from motion whose own
/// points reproject at least this many pixels off on average (COLMAP's mean reprojection
/// error): refinement raised the held-out PSNR of a phone video's model with a focal per
/// frame (1.08 px), and lowered it on COLMAP 4's models of the fox (0.61 px) and the temple
/// ring (0.24 px) (docs/own-scene.md#camera-refinement).
pub(crate) const AUTO_REFINE_RESIDUAL_PX: f64 = 0.8;

/// Whether training refines its cameras (`training.camera_refinement`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CameraRefinementMode {
    /// On for captures whose cameras structure from motion placed loosely: a COLMAP model
    /// whose 3D points reproject `AUTO_REFINE_RESIDUAL_PX` or more off on average. Off for
    /// cameras whose residual the files do not give (LLFF's `poses_bounds.npy`, a
    /// `transforms.json`), for cameras from a calibration or a renderer, and for
    /// NeRF-synthetic scenes, where refinement measured a loss.
    Auto,
    /// Always.
    On,
    /// Never: the default, since in runs of a few minutes refinement cost held-out PSNR on exact
    /// cameras and on COLMAP's (docs/own-scene.md#camera-refinement); it wins back what
    /// cameras off by a degree lose.
    #[default]
    Off,
}

/// `auto`, `on` or `off` (`true` and `false` too), as a config writes it
/// (`training.camera_refinement`).
impl<'de> serde::Deserialize<'de> for CameraRefinementMode {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct Mode;
        impl serde::de::Visitor<'_> for Mode {
            type Value = CameraRefinementMode;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("auto, on or off")
            }
            fn visit_bool<E: serde::de::Error>(
                self,
                on: bool,
            ) -> std::result::Result<Self::Value, E> {
                Ok(match on {
                    true => CameraRefinementMode::On,
                    false => CameraRefinementMode::Off,
                })
            }
            fn visit_str<E: serde::de::Error>(
                self,
                name: &str,
            ) -> std::result::Result<Self::Value, E> {
                match name {
                    "auto" => Ok(CameraRefinementMode::Auto),
                    "on" => Ok(CameraRefinementMode::On),
                    "off" => Ok(CameraRefinementMode::Off),
                    other => Err(E::custom(nerf_core::key_checks::unknown_name(
                        other,
                        &["auto", "on", "off"],
                    ))),
                }
            }
        }
        d.deserialize_any(Mode)
    }
}

impl CameraRefinementMode {
    /// Whether the cameras are refined when the training data's cameras are `from_sfm`,
    /// with the mean reprojection error `sfm_residual` (pixels) when the files give it.
    pub(crate) fn enabled(self, from_sfm: bool, sfm_residual: Option<f64>) -> bool {
        match self {
            Self::Auto => from_sfm && sfm_residual.is_some_and(|r| r >= AUTO_REFINE_RESIDUAL_PX),
            Self::On => true,
            Self::Off => false,
        }
    }
}

/// What `training.camera_refinement: auto` chose for a capture and why, as a log line:
/// `refined` as [`CameraRefinementMode::enabled`] decided for cameras `from_sfm` with the
/// mean reprojection error `sfm_residual`.
pub(crate) fn auto_choice(refined: bool, from_sfm: bool, sfm_residual: Option<f64>) -> String {
    let limit = AUTO_REFINE_RESIDUAL_PX;
    match (refined, from_sfm, sfm_residual) {
        (true, _, Some(r)) => format!(
            "refining the cameras: structure from motion's points reproject {r:.2} px off on \
             average ({limit} px or more: training.camera_refinement auto)"
        ),
        (_, false, _) => "cameras not refined: the capture shows no structure from motion (no \
            3D points, no COLMAP workspace beside it), so they are taken as exact \
            (training.camera_refinement=on refines them)"
            .to_string(),
        (_, true, Some(r)) => format!(
            "cameras not refined: structure from motion's points reproject {r:.2} px off on \
             average, under the {limit} px that auto refines from \
             (training.camera_refinement=on refines them)"
        ),
        (_, true, None) => "cameras not refined: the capture gives no residual of its \
            structure from motion (no 3D points with it), so they are taken as placed \
            (training.camera_refinement=on refines them)"
            .to_string(),
    }
}

/// The rotation matrices `(n, 3, 3)` of rotation vectors `omega` `(n, 3)` (axis times angle,
/// radians), as tensor ops (differentiable; in `omega`'s dtype): Rodrigues'
/// `R = I + A·K + B·K²` with `K` the cross-product matrix of `ω`, `A = sin θ / θ` and
/// `B = (1 − cos θ)/θ² = 2 sin²(θ/2)/θ²` (`θ = |ω|`), computed in f64, from their Taylor
/// series near `θ = 0`.
pub(crate) fn so3_exp(omega: &Tensor) -> Result<Tensor> {
    let dtype = omega.dtype();
    let w = omega.to_dtype(DType::F64)?;
    let n = w.dim(0)?;
    let theta_sq = w.sqr()?.sum_keepdim(1)?;
    let small = theta_sq.lt(SMALL_ANGLE_SQ)?;
    // Away from 0 (the other branch is picked there, and its gradient must stay finite).
    let safe_sq = theta_sq.maximum(SMALL_ANGLE_SQ)?;
    let theta = safe_sq.sqrt()?;
    let a_exact = theta.sin()?.div(&theta)?;
    let b_exact = (theta.affine(0.5, 0.0)?.sin()?.sqr()? * 2.0)?.div(&safe_sq)?;
    let theta_4 = theta_sq.sqr()?;
    let a_series = ((theta_sq.affine(-1.0 / 6.0, 1.0)? + (&theta_4 / 120.0)?)?).clone();
    let b_series = (theta_sq.affine(-1.0 / 24.0, 0.5)? + (&theta_4 / 720.0)?)?;
    let a = small.where_cond(&a_series, &a_exact)?.unsqueeze(2)?;
    let b = small.where_cond(&b_series, &b_exact)?.unsqueeze(2)?;
    let (x, y, z) = (w.narrow(1, 0, 1)?, w.narrow(1, 1, 1)?, w.narrow(1, 2, 1)?);
    let zero = x.zeros_like()?;
    let k = Tensor::cat(
        &[
            &zero,
            &z.neg()?,
            &y,
            &z,
            &zero,
            &x.neg()?,
            &y.neg()?,
            &x,
            &zero,
        ],
        1,
    )?
    .reshape((n, 3, 3))?;
    let k_sq = k.matmul(&k)?;
    let eye = Tensor::eye(3, DType::F64, w.device())?.unsqueeze(0)?;
    let r = eye
        .broadcast_add(&k.broadcast_mul(&a)?)?
        .add(&k_sq.broadcast_mul(&b)?)?;
    Ok(r.to_dtype(dtype)?)
}

/// The per-camera corrections being trained, and their optimiser.
pub struct CameraRefinement {
    corrections: Var,
    adam: SparseAdam,
    base_lr: f64,
    weight_decay: f64,
}

impl CameraRefinement {
    /// Zero corrections `(n_cameras, 6)` for the training cameras, their Adam at
    /// [`LEARNING_RATE`] with [`WEIGHT_DECAY`].
    pub(crate) fn new(n_cameras: usize, device: &Device) -> Result<Self> {
        let corrections = Var::zeros((n_cameras, 6), DType::F32, device)?;
        let mut adam = SparseAdam::new(CHECKPOINT_KEY, corrections.clone(), LEARNING_RATE)?;
        adam.eps = 1e-15;
        Ok(Self {
            corrections,
            adam,
            base_lr: LEARNING_RATE,
            weight_decay: WEIGHT_DECAY,
        })
    }

    /// `rays` (N of them, `(N, 3)` origins and directions) with ray `j` moved by the
    /// correction of camera `cameras[j]`: origins `o + t`, directions `R·d` (tracked by
    /// autograd through the corrections).
    pub(crate) fn apply(&self, rays: &Rays, cameras: &[u32]) -> Result<Rays> {
        let n = rays.len();
        ensure!(
            cameras.len() == n,
            "camera refinement: {} camera indices for {n} rays",
            cameras.len()
        );
        let c = self.corrections.as_tensor();
        let index = Tensor::from_vec(cameras.to_vec(), n, c.device())?;
        let rotation = so3_exp(&c.narrow(1, 0, 3)?)?.index_select(&index, 0)?;
        let translation = c.narrow(1, 3, 3)?.contiguous()?.index_select(&index, 0)?;
        let directions = rotation
            .broadcast_mul(&rays.directions.unsqueeze(1)?)?
            .sum(2)?;
        Ok(Rays {
            origins: rays.origins.add(&translation)?,
            directions,
            camera_index: rays.camera_index.clone(),
        })
    }

    /// Sets the learning rate to [`LEARNING_RATE`] times `factor` (the run's schedule: its
    /// learning rate over its initial one).
    pub(crate) fn set_lr_factor(&mut self, factor: f64) {
        self.adam.lr = self.base_lr * factor;
    }

    /// One Adam step from `grads` on the cameras whose correction has a gradient (those with
    /// rays in the step), weight decay added.
    pub(crate) fn step(&mut self, grads: &GradStore) -> Result<()> {
        let Some(g) = grads.get(self.corrections.as_tensor()) else {
            return Ok(());
        };
        let rows = nonzero_rows(g)?;
        let decayed = g.add(&(self.corrections.as_tensor() * self.weight_decay)?)?;
        self.adam.step(&decayed, &rows)
    }

    /// The corrections under [`CHECKPOINT_KEY`] and their optimiser's state.
    pub(crate) fn state_tensors(&self) -> Result<Vec<(String, Tensor)>> {
        let mut out = vec![(
            CHECKPOINT_KEY.to_string(),
            self.corrections.as_tensor().clone(),
        )];
        out.extend(self.adam.state_tensors()?);
        Ok(out)
    }

    /// Restores what [`CameraRefinement::state_tensors`] saved; `false` (and nothing
    /// changed) when `tensors` hold no corrections (a checkpoint written without camera
    /// refinement); an error when they are for another number of cameras.
    pub(crate) fn load_state(&mut self, tensors: &HashMap<String, Tensor>) -> Result<bool> {
        let Some(saved) = tensors.get(CHECKPOINT_KEY) else {
            return Ok(false);
        };
        ensure!(
            saved.dims() == self.corrections.dims(),
            "checkpoint tensor {CHECKPOINT_KEY} has shape {:?}, but this run refines {} \
             cameras (shape {:?}): was it trained on another capture?",
            saved.dims(),
            self.corrections.dim(0)?,
            self.corrections.dims()
        );
        self.corrections.set(
            &saved
                .to_dtype(DType::F32)?
                .to_device(self.corrections.device())?,
        )?;
        self.adam.load_state(tensors)?;
        Ok(true)
    }

    /// Each camera's correction as (rotation angle in degrees, translation length).
    pub(crate) fn sizes(&self) -> Result<Vec<(f64, f64)>> {
        let c = self.corrections.as_tensor().to_dtype(DType::F64)?;
        Ok(c.to_vec2::<f64>()?
            .iter()
            .map(|r| {
                let angle = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
                let shift = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
                (angle.to_degrees(), shift)
            })
            .collect())
    }

    /// A one-line summary: mean and largest rotation and translation of the corrections.
    pub(crate) fn summary(&self) -> Result<String> {
        let sizes = self.sizes()?;
        let n = sizes.len().max(1) as f64;
        let (mean_r, mean_t) = sizes
            .iter()
            .fold((0.0, 0.0), |(a, b), (r, t)| (a + r / n, b + t / n));
        let max_r = sizes.iter().map(|s| s.0).fold(0.0, f64::max);
        let max_t = sizes.iter().map(|s| s.1).fold(0.0, f64::max);
        Ok(format!(
            "camera refinement of {} cameras: rotation mean {mean_r:.3}° (max {max_r:.3}°), \
             translation mean {mean_t:.4} (max {max_t:.4}) in the normalised frame",
            sizes.len()
        ))
    }

    /// The refined poses as JSON: per training frame (in `frames`' order) its image, the
    /// correction (rotation vector in radians, translation), and the camera centre before and
    /// after, in the normalised frame the model was trained in. A refined camera's rays leave
    /// from `centre + translation` in the directions `R(rotation)·d` of the given camera's.
    pub(crate) fn poses_json(&self, frames: &[Frame]) -> Result<serde_json::Value> {
        let c = self.corrections.as_tensor().to_dtype(DType::F64)?;
        let rows = c.to_vec2::<f64>()?;
        ensure!(rows.len() == frames.len(), "camera refinement: frame count");
        let cameras: Vec<serde_json::Value> = frames
            .iter()
            .zip(&rows)
            .map(|(frame, r)| {
                let centre = frame.camera.center();
                serde_json::json!({
                    "image": frame.file_path.display().to_string(),
                    "rotation_vector": [r[0], r[1], r[2]],
                    "rotation_degrees": (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt().to_degrees(),
                    "translation": [r[3], r[4], r[5]],
                    "centre": [centre.x, centre.y, centre.z],
                    "refined_centre": [centre.x + r[3], centre.y + r[4], centre.z + r[5]],
                })
            })
            .collect();
        Ok(serde_json::json!({
            "frame": "normalised (the checkpoint's scene_transform)",
            "cameras": cameras,
        }))
    }
}

/// Writes the refined poses of `refinement` for `frames` to `path` (atomically).
pub(crate) fn write_poses(
    refinement: &CameraRefinement,
    frames: &[Frame],
    path: &std::path::Path,
) -> Result<()> {
    let json = refinement.poses_json(frames)?;
    nerf_files::output::write_atomically(path, |w| {
        serde_json::to_writer_pretty(&mut *w, &json)?;
        use std::io::Write;
        writeln!(w)?;
        Ok(())
    })
    .with_context(|| format!("cannot write the refined cameras {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, DVec3};

    #[test]
    fn auto_refines_only_cameras_their_own_points_call_loose() {
        use CameraRefinementMode::*;
        let loose = Some(AUTO_REFINE_RESIDUAL_PX + 0.3);
        let tight = Some(AUTO_REFINE_RESIDUAL_PX - 0.3);
        assert!(Auto.enabled(true, loose));
        assert!(!Auto.enabled(true, tight));
        assert!(!Auto.enabled(true, None));
        assert!(!Auto.enabled(false, loose));
        assert!(On.enabled(false, None) && !Off.enabled(true, loose));
        // The log line says which and why.
        assert!(auto_choice(true, true, loose).starts_with("refining the cameras"));
        let under = auto_choice(false, true, tight);
        assert!(under.contains("under the 0.8 px"), "{under}");
        assert!(auto_choice(false, true, None).contains("no residual"));
        assert!(auto_choice(false, false, None).contains("no structure from motion"));
    }

    fn rotation(omega: [f64; 3]) -> Vec<Vec<f64>> {
        let t = Tensor::new(&[omega], &Device::Cpu).unwrap();
        so3_exp(&t).unwrap().squeeze(0).unwrap().to_vec2().unwrap()
    }

    #[test]
    fn so3_exp_matches_quaternion_rotations() {
        for omega in [
            [0.0, 0.0, 0.0],
            [1e-6, -2e-6, 5e-7],
            [0.3, -0.1, 0.2],
            [0.0, 0.0, std::f64::consts::FRAC_PI_2],
            [-1.0, 2.0, 0.5],
        ] {
            let r = rotation(omega);
            let q = DQuat::from_scaled_axis(DVec3::from_array(omega));
            for (j, axis) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
                let col = q * axis;
                for i in 0..3 {
                    assert!(
                        (r[i][j] - col[i]).abs() < 1e-12,
                        "{omega:?}: R[{i}][{j}] = {}, want {}",
                        r[i][j],
                        col[i]
                    );
                }
            }
        }
    }

    #[test]
    fn so3_exp_gradient_matches_finite_differences() {
        // At zero, ∂R/∂ω_a is the cross-product matrix of e_a; elsewhere central differences.
        for omega in [[0.0, 0.0, 0.0], [1e-5, 0.0, -2e-5], [0.4, -0.3, 0.7]] {
            let weights: Vec<f64> = (0..9).map(|i| (i as f64 * 0.37).sin()).collect();
            let wt = Tensor::from_vec(weights.clone(), (1, 3, 3), &Device::Cpu).unwrap();
            let v = Var::new(&[omega], &Device::Cpu).unwrap();
            let loss = so3_exp(v.as_tensor())
                .unwrap()
                .mul(&wt)
                .unwrap()
                .sum_all()
                .unwrap();
            let g = loss.backward().unwrap();
            let g = g.get(v.as_tensor()).unwrap().to_vec2::<f64>().unwrap()[0].clone();
            let f = |w: [f64; 3]| -> f64 {
                let r = rotation(w);
                (0..9).map(|k| r[k / 3][k % 3] * weights[k]).sum()
            };
            for a in 0..3 {
                let eps = 1e-6;
                let (mut hi, mut lo) = (omega, omega);
                hi[a] += eps;
                lo[a] -= eps;
                let fd = (f(hi) - f(lo)) / (2.0 * eps);
                assert!(
                    g[a].is_finite() && (g[a] - fd).abs() < 1e-7,
                    "{omega:?} axis {a}: {} vs {fd}",
                    g[a]
                );
            }
        }
    }

    #[test]
    fn corrections_move_the_rays_of_their_camera_only() {
        let dev = Device::Cpu;
        let mut cams = CameraRefinement::new(3, &dev).unwrap();
        let rays = Rays {
            origins: Tensor::new(&[[1f32, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], &dev)
                .unwrap(),
            directions: Tensor::new(
                &[[0f32, 0.0, -1.0], [0.0, -1.0, 0.0], [-0.6, 0.0, -0.8]],
                &dev,
            )
            .unwrap(),
            camera_index: None,
        };
        // Zero corrections leave the rays exactly as they are.
        let same = cams.apply(&rays, &[0, 2, 1]).unwrap();
        assert_eq!(
            same.directions.to_vec2::<f32>().unwrap(),
            rays.directions.to_vec2::<f32>().unwrap()
        );
        assert_eq!(
            same.origins.to_vec2::<f32>().unwrap(),
            rays.origins.to_vec2::<f32>().unwrap()
        );
        // Camera 2 turned 90° about z and moved by (0.1, 0, 0).
        let mut c = [[0f32; 6]; 3];
        c[2] = [0.0, 0.0, std::f32::consts::FRAC_PI_2, 0.1, 0.0, 0.0];
        let c_t = Tensor::from_vec(c.concat(), (3, 6), &dev).unwrap();
        cams.corrections.set(&c_t).unwrap();
        let moved = cams.apply(&rays, &[0, 2, 1]).unwrap();
        let o = moved.origins.to_vec2::<f32>().unwrap();
        let d = moved.directions.to_vec2::<f32>().unwrap();
        assert_eq!(o[0], [1.0, 0.0, 0.0]);
        assert_eq!(o[2], [0.0, 0.0, 1.0]);
        assert!((o[1][0] - 0.1).abs() < 1e-7 && o[1][1] == 1.0);
        // R_z(90°)·(0, −1, 0) = (1, 0, 0).
        assert!(
            (d[1][0] - 1.0).abs() < 1e-6 && d[1][1].abs() < 1e-6,
            "{:?}",
            d[1]
        );
        assert_eq!(d[0], [0.0, 0.0, -1.0]);
        // The state round-trips; a checkpoint without it is reported, one for another count
        // of cameras refused.
        let saved: HashMap<String, Tensor> = cams.state_tensors().unwrap().into_iter().collect();
        let mut other = CameraRefinement::new(3, &dev).unwrap();
        assert!(!other.load_state(&HashMap::new()).unwrap());
        assert!(other.load_state(&saved).unwrap());
        assert_eq!(
            other.corrections.as_tensor().to_vec2::<f32>().unwrap(),
            c.iter().map(|r| r.to_vec()).collect::<Vec<_>>()
        );
        let mut four = CameraRefinement::new(4, &dev).unwrap();
        let err = four.load_state(&saved).unwrap_err().to_string();
        assert!(err.contains("camera_refinement"), "{err}");
        cams.set_lr_factor(0.5);
        assert_eq!(cams.adam.lr, 0.5 * LEARNING_RATE);
    }

    #[test]
    fn a_step_moves_only_the_cameras_with_rays_and_recovers_a_known_turn() {
        // Rays of camera 1 should hit the points a turn of 0.02 rad about y makes of them; the
        // loss is the squared distance of the unit-depth points. Camera 0 has no rays.
        let dev = Device::Cpu;
        let mut cams = CameraRefinement::new(2, &dev).unwrap();
        cams.weight_decay = 0.0;
        cams.base_lr = 2e-3;
        cams.set_lr_factor(1.0);
        let dirs = [[0.0f32, 0.0, -1.0], [0.3, 0.0, -0.95], [0.0, 0.4, -0.9]];
        let truth = DQuat::from_scaled_axis(DVec3::new(0.0, 0.02, 0.0));
        let target: Vec<[f32; 3]> = dirs
            .iter()
            .map(|d| {
                let v = truth * DVec3::new(d[0] as f64, d[1] as f64, d[2] as f64);
                [v.x as f32, v.y as f32, v.z as f32]
            })
            .collect();
        let rays = Rays {
            origins: Tensor::zeros((3, 3), DType::F32, &dev).unwrap(),
            directions: Tensor::new(&dirs, &dev).unwrap(),
            camera_index: None,
        };
        let target = Tensor::from_vec(target.concat(), (3, 3), &dev).unwrap();
        for _ in 0..300 {
            let moved = cams.apply(&rays, &[1, 1, 1]).unwrap();
            let loss = (moved.directions - &target)
                .unwrap()
                .sqr()
                .unwrap()
                .sum_all()
                .unwrap();
            cams.step(&loss.backward().unwrap()).unwrap();
        }
        let c = cams.corrections.as_tensor().to_vec2::<f32>().unwrap();
        assert_eq!(c[0], [0.0; 6], "a camera without rays moved");
        assert!((c[1][1] - 0.02).abs() < 2e-3, "{:?}", c[1]);
    }

    #[test]
    fn the_gradient_through_a_rendered_hash_grid_matches_finite_differences() {
        // The whole chain: corrections → rays → packed points (tensor ops) → contraction →
        // hash encoding (its point gradient, fused) → MLPs → compositing.
        use nerf_core::contraction::Contraction;
        use nerf_field::ngp::{NgpField, NgpParams, NgpState, TABLE};
        use nerf_render::occupancy::{OccupancyGrid, OccupancyGridParams};
        use nerf_render::occupied_field::OccupiedField;
        use nerf_render::renderer::VolumeRenderer;
        use nerf_render::sampler::StratifiedSampler;
        let dev = Device::Cpu;
        let params = NgpParams {
            log2_hashmap_size: 10,
            max_resolution: Some(24.0),
            aabb: [[-2.0; 3], [2.0; 3]],
            contraction: Contraction::LInf,
            ..nerf_field::ngp::small_test_params()
        };
        let state = NgpState::seeded(&params, 3, &dev).unwrap();
        let table = state.varmap.data().lock().unwrap()[TABLE].clone();
        let n = table.elem_count();
        let values: Vec<f32> = (0..n).map(|i| (i as f32 * 0.731).sin()).collect();
        table
            .set(&Tensor::from_vec(values, table.shape(), &dev).unwrap())
            .unwrap();
        let grid = OccupancyGrid::new(&OccupancyGridParams {
            resolution: 16,
            aabb: [-2.0, -2.0, -2.0, 2.0, 2.0, 2.0],
            density_threshold: 0.01,
            contraction: Contraction::LInf,
        })
        .unwrap();
        let field = OccupiedField {
            field: Box::new(NgpField {
                model: state.model.clone(),
                camera_index: None,
            }),
            grid: std::sync::Arc::new(grid),
        };
        let renderer = VolumeRenderer::new(4096, false).unwrap();
        assert!(renderer.skips_samples(&field));
        let sampler = StratifiedSampler::new(40, 0.05, 4.0).unwrap();
        let camera = nerf_core::camera::surround_cameras(1.2, 3, DVec3::Z, 2.0)[1];
        let rays = Rays::for_image(&nerf_core::camera::Camera::from(camera), 5, 4, &dev).unwrap();
        let cameras = vec![0u32; rays.len()];
        let weights: Vec<f32> = (0..rays.len() * 3)
            .map(|i| (i as f32 * 1.3).cos())
            .collect();
        let weights = Tensor::from_vec(weights, (rays.len(), 3), &dev).unwrap();
        let refinement = CameraRefinement::new(1, &dev).unwrap();
        let base = [0.01f32, -0.02, 0.015, 0.01, 0.0, -0.02];
        let loss_at = |c: [f32; 6]| -> Tensor {
            let t = Tensor::from_vec(c.to_vec(), (1, 6), &dev).unwrap();
            refinement.corrections.set(&t).unwrap();
            let moved = refinement.apply(&rays, &cameras).unwrap();
            let out = renderer.render(&field, &sampler, &moved, None).unwrap();
            (out.color.mul(&weights).unwrap().sum_all().unwrap() + out.depth.sum_all().unwrap())
                .unwrap()
        };
        let grads = loss_at(base).backward().unwrap();
        let g = grads.get(refinement.corrections.as_tensor()).unwrap();
        let g = g.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let scalar = |c| loss_at(c).to_scalar::<f32>().unwrap() as f64;
        for k in 0..6 {
            let eps = 2e-3;
            let (mut hi, mut lo) = (base, base);
            hi[k] += eps;
            lo[k] -= eps;
            let fd = (scalar(hi) - scalar(lo)) / (2.0 * eps as f64);
            assert!(
                (g[k] as f64 - fd).abs() < 0.03 * fd.abs() + 0.02,
                "parameter {k}: gradient {}, finite difference {fd}",
                g[k]
            );
        }
        assert!(g.iter().any(|v| v.abs() > 0.1), "{g:?}");
    }
}
