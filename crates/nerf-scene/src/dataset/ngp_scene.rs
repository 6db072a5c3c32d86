//! instant-ngp's scene keys at the top of `transforms.json`, read and checked, and why they
//! change nothing here.
//!
//! * `scale` and `offset` (and `aabb`, which instant-ngp turns into them): instant-ngp maps
//!   every camera position `p` to `scale · p + offset` (in its own axis order) and leaves the
//!   orientations alone. That is a uniform scaling and a translation of the whole rig, and
//!   the capture normalisation ([`super::normalize::SceneTransform::from_poses`]: mean up,
//!   focus or median centre, farthest-inlier scale) undoes any such map exactly, so the
//!   normalised cameras are the same with or without them (the test below). A `scale` that
//!   is not positive would mirror the positions but not the orientations, and is refused.
//! * `aabb_scale`: the side of instant-ngp's scene box in its own units (1 is its unit cube,
//!   into which `scale` 0.33 brings colmap2nerf's cameras). Here the scene box is the
//!   config's (`nerf_scene`: `[-1, 1]³` around the normalised cameras; a scene contraction
//!   covers all of space), so it is only checked.
//! * `n_frames` (keep the first N frames) and `sharpness_discard_threshold` (drop frames
//!   blurrier than their neighbours by their `sharpness`): instant-ngp trains on fewer frames
//!   than the file lists. Neither is done here, so a file that asks for it is refused, rather
//!   than trained on frames instant-ngp would not use; colmap2nerf writes neither.

use anyhow::{bail, ensure, Result};
use serde::Deserialize;

/// instant-ngp's scene keys, each optional.
#[derive(Debug, Clone, Default, Deserialize)]
pub(crate) struct NgpSceneKeys {
    aabb_scale: Option<f64>,
    scale: Option<f64>,
    offset: Option<serde_json::Value>,
    n_frames: Option<f64>,
    sharpness_discard_threshold: Option<f64>,
}

impl NgpSceneKeys {
    /// An error naming the first key whose value instant-ngp would not load as this loader
    /// does, in a file of `frames` frames (see the module documentation).
    pub(crate) fn check(&self, frames: usize) -> Result<()> {
        if let Some(a) = self.aabb_scale {
            ensure!(
                a.is_finite() && a > 0.0,
                "aabb_scale = {a} is not a positive number"
            );
        }
        if let Some(s) = self.scale {
            ensure!(
                s.is_finite() && s > 0.0,
                "scale = {s} is not a positive number (instant-ngp multiplies the camera \
                 positions by it)"
            );
        }
        if let Some(offset) = &self.offset {
            let numbers: Option<Vec<f64>> = match offset {
                serde_json::Value::Array(values) if values.len() == 3 => {
                    values.iter().map(|v| v.as_f64()).collect()
                }
                serde_json::Value::Number(n) => n.as_f64().map(|v| vec![v]),
                _ => None,
            };
            if numbers.is_none_or(|n| n.iter().any(|v| !v.is_finite())) {
                bail!("offset = {offset} is not a number or a list of 3 numbers");
            }
        }
        if let Some(n) = self.n_frames {
            ensure!(
                n >= frames as f64,
                "n_frames = {n}: instant-ngp would train on only the first {n} of the {frames} \
                 frames, which this loader does not do; list only those frames"
            );
        }
        if let Some(t) = self.sharpness_discard_threshold {
            ensure!(
                t.is_finite() && t <= 0.0,
                "sharpness_discard_threshold = {t}: dropping frames by their sharpness is not \
                 supported; list only the frames to train on"
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::normalize::SceneTransform;
    use glam::{DMat3, DVec3};
    use nerf_core::camera::ColmapPose;

    /// A camera at `eye` looking at `at`, its up near +y (OpenCV axes: +y down, +z forward).
    fn looking_at(eye: DVec3, at: DVec3) -> ColmapPose {
        let forward = (at - eye).normalize();
        let right = forward.cross(DVec3::Y).normalize();
        let down = forward.cross(right);
        let rotation = DMat3::from_cols(right, down, forward).transpose();
        ColmapPose {
            rotation,
            translation: -(rotation * eye),
        }
    }

    /// The normalised poses of `poses`.
    fn normalised(poses: &[ColmapPose]) -> Vec<ColmapPose> {
        let t = SceneTransform::from_poses(poses).unwrap();
        poses.iter().map(|p| t.apply_pose(p)).collect()
    }

    /// instant-ngp's `scale` and `offset` applied to `poses`: the centres moved, the
    /// orientations kept.
    fn ngp_moved(poses: &[ColmapPose], scale: f64, offset: DVec3) -> Vec<ColmapPose> {
        poses
            .iter()
            .map(|p| {
                let centre = scale * p.center() + offset;
                ColmapPose {
                    rotation: p.rotation,
                    translation: -(p.rotation * centre),
                }
            })
            .collect()
    }

    #[test]
    fn scale_and_offset_change_no_normalised_camera() {
        // A ring converging on a point (focus centring), and a forward-facing row (median).
        let ring: Vec<ColmapPose> = (0..12)
            .map(|i| {
                let a = i as f64 * 0.5;
                let eye = DVec3::new(4.0 * a.cos(), 1.0 + 0.1 * a, 4.0 * a.sin());
                looking_at(eye, DVec3::new(0.3, 0.2, -0.1))
            })
            .collect();
        let row: Vec<ColmapPose> = (0..9)
            .map(|i| {
                let eye = DVec3::new(i as f64 * 0.3, 0.05 * (i % 3) as f64, 0.0);
                looking_at(eye, eye + DVec3::new(0.0, 0.0, 5.0))
            })
            .collect();
        for poses in [ring, row] {
            let reference = normalised(&poses);
            for (scale, offset) in [(0.33, DVec3::splat(0.5)), (7.0, DVec3::new(-3.0, 2.0, 9.0))] {
                let moved = normalised(&ngp_moved(&poses, scale, offset));
                for (a, b) in reference.iter().zip(&moved) {
                    let rotation = (a.rotation - b.rotation).to_cols_array();
                    assert!(rotation.iter().all(|v| v.abs() < 1e-9), "{a:?} {b:?}");
                    assert!(
                        (a.translation - b.translation).length() < 1e-9,
                        "{a:?} {b:?}"
                    );
                }
            }
            // A negative scale mirrors the centres but not the orientations: another rig.
            let mirrored = normalised(&ngp_moved(&poses, -1.0, DVec3::ZERO));
            assert!(reference
                .iter()
                .zip(&mirrored)
                .any(|(a, b)| (a.center() - b.center()).length() > 1e-3));
        }
    }

    #[test]
    fn keys_instant_ngp_would_load_otherwise_are_named() {
        let check = |json: &str, frames| {
            serde_json::from_str::<NgpSceneKeys>(json)
                .unwrap()
                .check(frames)
        };
        check(
            r#"{"aabb_scale": 16, "scale": 0.5, "offset": [0.5, 0.5, 0.5], "n_frames": 4}"#,
            4,
        )
        .unwrap();
        check(r#"{"offset": 0.5, "sharpness_discard_threshold": 0}"#, 4).unwrap();
        for (json, says) in [
            (r#"{"aabb_scale": 0}"#, "aabb_scale = 0"),
            (r#"{"scale": -0.33}"#, "scale = -0.33"),
            (r#"{"offset": [1, 2]}"#, "offset = [1,2]"),
            (r#"{"offset": "x"}"#, "offset = \"x\""),
            (
                r#"{"n_frames": 3}"#,
                "n_frames = 3: instant-ngp would train on only",
            ),
            (
                r#"{"sharpness_discard_threshold": 0.5}"#,
                "sharpness_discard_threshold = 0.5",
            ),
        ] {
            let err = check(json, 4).unwrap_err().to_string();
            assert!(err.starts_with(says), "{json}: {err}");
        }
    }
}
