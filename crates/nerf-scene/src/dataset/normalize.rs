//! Scene normalisation for captures, whose world frame is whatever structure from motion
//! chose: the cameras are oriented (their mean up vector becomes world +z), centred (the point
//! their optical axes converge on goes to the origin, or, when they do not converge, as in a
//! forward-facing capture, the per-axis median of the camera centres) and scaled (the farthest
//! camera that is not an outlier lands at distance 1), as nerfstudio's
//! `auto_orient_and_center_poses` ("up", "focus" or "poses") and `auto_scale_poses` do, with a
//! median and an outlier cut so that a few stray cameras do not move the scene.

use anyhow::{bail, Result};
use glam::{DMat3, DVec3};

use nerf_core::camera::ColmapPose;
use nerf_core::term::short_number;

/// A camera farther from the centre than this many times the median distance is an outlier
/// and does not set the scale.
pub(crate) const OUTLIER_DISTANCE_FACTOR: f64 = 3.0;

/// The similarity transform applied to a capture: `X' = scale · rotation · (X − center)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneTransform {
    /// Rotation taking the capture's mean camera up vector to world +z.
    pub rotation: DMat3,
    /// The capture's centre, in its own frame.
    pub center: DVec3,
    /// Scale factor (> 0).
    pub scale: f64,
}

/// The finest float64 spacing at the cameras' farthest coordinate, as a fraction of their
/// spread, at which their positions still count as known: centres shifted by 1e17 with a
/// spread of 4 sit on a 16-unit float64 grid, and normalise to nothing.
pub(crate) const MIN_RESOLVED_FRACTION: f64 = 1e-6;

impl SceneTransform {
    /// Orientation, centre and scale from the cameras' world → camera poses (see the module
    /// documentation). An error when there is no camera or the cameras all stand at one point.
    pub(crate) fn from_poses(poses: &[ColmapPose]) -> Result<Self> {
        if poses.is_empty() {
            bail!("no cameras to normalise the scene by");
        }
        // OpenCV camera axes: +y is down, so the camera's up is −y, in world space the
        // second row of the world → camera rotation, negated.
        let up: DVec3 = poses.iter().map(|p| -p.rotation.row(1)).sum();
        let rotation = if up.length() > 1e-9 {
            rotation_between(up.normalize(), DVec3::Z)
        } else {
            DMat3::IDENTITY
        };
        let centers: Vec<DVec3> = poses.iter().map(|p| rotation * p.center()).collect();
        let median_of = |k: usize| median(centers.iter().map(|c| c[k]).collect());
        let axes: Vec<(DVec3, DVec3)> = poses
            .iter()
            .map(|p| (p.center(), p.rotation.row(2)))
            .collect();
        let center_rotated = match focus_of_axes(&axes) {
            Some(focus) => rotation * focus,
            None => DVec3::new(median_of(0), median_of(1), median_of(2)),
        };
        let distances: Vec<f64> = centers
            .iter()
            .map(|c| (*c - center_rotated).length())
            .collect();
        let typical = median(distances.clone());
        let radius = distances
            .iter()
            .copied()
            .filter(|&d| d <= OUTLIER_DISTANCE_FACTOR * typical)
            .fold(0.0, f64::max);
        if !(radius.is_finite() && radius > 1e-12) {
            bail!("the cameras all stand at one point: the scene has no scale");
        }
        let farthest = centers
            .iter()
            .map(|c| c.abs().max_element())
            .fold(0.0, f64::max);
        let resolution = farthest * f64::EPSILON;
        if resolution > MIN_RESOLVED_FRACTION * radius {
            bail!(
                "the cameras stand {} apart but {} from the origin, where float64 resolves \
                 positions only to {}, more than {} of their spread: move the capture's \
                 origin near its cameras",
                short_number(radius),
                short_number(farthest),
                short_number(resolution),
                short_number(MIN_RESOLVED_FRACTION)
            );
        }
        Ok(Self {
            rotation,
            center: rotation.transpose() * center_rotated,
            scale: 1.0 / radius,
        })
    }

    /// The transform as text, for a checkpoint's metadata: the rotation's nine entries row
    /// by row, the centre's three coordinates and the scale, separated by spaces, each in
    /// the shortest decimal that reads back to the same `f64` ([`SceneTransform::from_text`]
    /// restores it exactly).
    pub fn to_text(&self) -> String {
        let r = self.rotation.transpose().to_cols_array();
        r.iter()
            .chain(&self.center.to_array())
            .chain(std::iter::once(&self.scale))
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// The transform [`SceneTransform::to_text`] wrote; an error saying what is wrong when
    /// the text is not 13 numbers or not a similarity (`SceneTransform::validate`).
    pub fn from_text(text: &str) -> Result<Self> {
        let values = text
            .split_whitespace()
            .map(|v| v.parse::<f64>())
            .collect::<std::result::Result<Vec<f64>, _>>()
            .map_err(|e| anyhow::anyhow!("not a list of numbers ({e})"))?;
        let Ok(values) = <[f64; 13]>::try_from(values.as_slice()) else {
            bail!("{} numbers, expected 13", values.len());
        };
        let rows: [f64; 9] = values[..9].try_into().expect("9 numbers");
        let transform = Self {
            rotation: DMat3::from_cols_array(&rows).transpose(),
            center: DVec3::new(values[9], values[10], values[11]),
            scale: values[12],
        };
        transform.validate()?;
        Ok(transform)
    }

    /// An error unless every number is finite, the scale positive and the rotation a
    /// rotation (orthonormal, determinant 1, to 1e-6).
    pub(crate) fn validate(&self) -> Result<()> {
        let finite = self.rotation.is_finite() && self.center.is_finite();
        if !(finite && self.scale.is_finite() && self.scale > 0.0) {
            bail!("not finite, or a scale that is not positive");
        }
        let off = (self.rotation * self.rotation.transpose() - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, b| a.max(b.abs()));
        if off > 1e-6 || (self.rotation.determinant() - 1.0).abs() > 1e-6 {
            bail!("the rotation is not a rotation");
        }
        Ok(())
    }

    /// Whether `other` puts every point of the cameras' unit ball where this one does, to
    /// within `tolerance` in the normalised frame: rotations, centres (in normalised units)
    /// and the log of the scales all agree that closely.
    pub fn agrees_with(&self, other: &SceneTransform, tolerance: f64) -> bool {
        let rotation = (self.rotation - other.rotation)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, b| a.max(b.abs()));
        let center = self.scale * (self.center - other.center).length();
        let scale = (self.scale / other.scale).ln().abs();
        rotation <= tolerance && center <= tolerance && scale <= tolerance
    }

    /// A world point in the normalised frame.
    pub fn apply_point(&self, point: DVec3) -> DVec3 {
        self.scale * (self.rotation * (point - self.center))
    }

    /// A world → camera pose in the normalised frame, imaging every point where the original
    /// imaged it: with `X = Rᵀ X'/s + c`, the camera point scaled by `s` is
    /// `(R_c Rᵀ) X' + s (R_c c + t_c)`.
    pub(crate) fn apply_pose(&self, pose: &ColmapPose) -> ColmapPose {
        let rotation = pose.rotation * self.rotation.transpose();
        ColmapPose {
            rotation,
            translation: self.scale * (pose.rotation * self.center + pose.translation),
        }
    }
}

/// Smallest `det(Σ (I − d dᵀ)) / n³` (a product of the normalised eigenvalues, none above
/// one) for which the cameras' optical axes are taken to converge: a ring of cameras gives
/// about 0.25, parallel axes (a forward-facing capture) 0.
const MIN_FOCUS_CONDITION: f64 = 1e-3;

/// The point nearest to every camera's optical axis in the least-squares sense (nerfstudio's
/// "focus" centring): `p = (Σ Mᵢ)⁻¹ Σ Mᵢ cᵢ` with `Mᵢ = I − dᵢ dᵢᵀ`, each axis given as its
/// camera centre `cᵢ` and viewing direction `dᵢ` (any length). `None` when the axes are
/// (nearly) parallel or the point lies behind most cameras: the normaliser uses the per-axis
/// median of the centres then, and the spiral path another focus depth.
pub(crate) fn focus_of_axes(axes: &[(DVec3, DVec3)]) -> Option<DVec3> {
    let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
    for (centre, direction) in axes {
        let d = direction.normalize();
        let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * *centre;
    }
    let n = axes.len() as f64;
    let condition = a.determinant() / n.powi(3);
    if condition.is_nan() || condition <= MIN_FOCUS_CONDITION {
        return None;
    }
    let focus = a.inverse() * b;
    let in_front = axes
        .iter()
        .filter(|(centre, direction)| (focus - *centre).dot(*direction) > 0.0)
        .count();
    (focus.is_finite() && 2 * in_front > axes.len()).then_some(focus)
}

/// The rotation taking unit vector `from` to unit vector `to` (Rodrigues; a half turn about
/// an axis perpendicular to `from` when they are opposite).
pub(crate) fn rotation_between(from: DVec3, to: DVec3) -> DMat3 {
    let axis = from.cross(to);
    let cos = from.dot(to).clamp(-1.0, 1.0);
    if axis.length() < 1e-12 {
        if cos > 0.0 {
            return DMat3::IDENTITY;
        }
        return DMat3::from_axis_angle(from.any_orthonormal_vector(), std::f64::consts::PI);
    }
    DMat3::from_axis_angle(axis.normalize(), cos.acos())
}

/// The median of `values` (the mean of the middle two for an even count); NaN-free input.
fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n.is_multiple_of(2) {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    } else {
        values[n / 2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::camera::Camera;
    use nerf_core::camera::ColmapCamera;

    /// Cameras on a circle of radius 3 about (5, −2, 1) in a frame where "up" is world +x,
    /// all looking at the centre, plus one outlier far away.
    fn tilted_ring() -> Vec<ColmapPose> {
        let centre = DVec3::new(5.0, -2.0, 1.0);
        let up = DVec3::X;
        let mut poses: Vec<ColmapPose> = (0..12)
            .map(|i| {
                let a = i as f64 / 12.0 * std::f64::consts::TAU;
                let eye = centre + 3.0 * DVec3::new(0.3, a.cos(), a.sin());
                look_at(eye, centre, up)
            })
            .collect();
        poses.push(look_at(centre + DVec3::new(0.0, 40.0, 0.0), centre, up));
        poses
    }

    /// An OpenCV world → camera pose at `eye` looking at `target` with image up along `up`.
    fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> ColmapPose {
        let z = (target - eye).normalize();
        let x = z.cross(-up).normalize(); // right = forward × down
        let y = z.cross(x); // down
        let rotation = DMat3::from_cols(x, y, z).transpose();
        ColmapPose {
            rotation,
            translation: -(rotation * eye),
        }
    }

    #[test]
    fn cameras_are_oriented_centred_and_scaled_ignoring_the_outlier() {
        let poses = tilted_ring();
        let t = SceneTransform::from_poses(&poses).unwrap();
        let centres: Vec<DVec3> = poses[..12]
            .iter()
            .map(|p| t.apply_pose(p).center())
            .collect();
        // The ring's cameras lie at distance 1 (all equally far; the outlier is left out of
        // the scale) around the origin, up to the median's offset along the ring's axis.
        for c in &centres {
            assert!((c.length() - 1.0).abs() < 1e-9, "{c}");
        }
        // Every camera's up (−y) is now close to +z: the mean up vector is exactly +z.
        let up: DVec3 = poses.iter().map(|p| -t.apply_pose(p).rotation.row(1)).sum();
        assert!((up.normalize() - DVec3::Z).length() < 1e-12);
        // The transform maps each centre as the pose does.
        for p in &poses {
            let moved = t.apply_point(p.center());
            assert!((moved - t.apply_pose(p).center()).length() < 1e-9);
        }
    }

    #[test]
    fn a_point_projects_to_the_same_pixel_after_normalisation() {
        let poses = tilted_ring();
        let t = SceneTransform::from_poses(&poses).unwrap();
        let params = [500.0, 480.0, 320.0, 240.0, -0.05, 0.01, 1e-3, -1e-3];
        let point = DVec3::new(5.3, -1.8, 1.4);
        for pose in &poses[..12] {
            let before = ColmapCamera::from_colmap("OPENCV", &params, (640, 480), *pose).unwrap();
            let after =
                ColmapCamera::from_colmap("OPENCV", &params, (640, 480), t.apply_pose(pose))
                    .unwrap();
            let (u, v) = before.project(point).unwrap();
            let (u2, v2) = after.project(t.apply_point(point)).unwrap();
            assert!(
                (u - u2).abs() < 1e-7 && (v - v2).abs() < 1e-7,
                "{u},{v} vs {u2},{v2}"
            );
            // And the ray through that pixel passes through the moved point.
            let (o, d) = after.ray_through_pixel(u2, v2);
            let q = t.apply_point(point) - o;
            assert!((q - d * q.dot(d)).length() < 1e-7);
            assert!(Camera::from(after.clone()).validate().is_ok());
        }
    }

    #[test]
    fn converging_cameras_centre_on_their_focus_and_parallel_ones_on_their_median() {
        // Cameras on a ring about (5, −2, 1), all looking at (5, −2, 0.2), below the ring's
        // plane: the focus, not the ring's centre, goes to the origin.
        let target = DVec3::new(5.0, -2.0, 0.2);
        let poses: Vec<ColmapPose> = (0..8)
            .map(|i| {
                let a = i as f64 / 8.0 * std::f64::consts::TAU;
                let eye = DVec3::new(5.0 + 2.0 * a.cos(), -2.0 + 2.0 * a.sin(), 1.0);
                look_at(eye, target, DVec3::Z)
            })
            .collect();
        let t = SceneTransform::from_poses(&poses).unwrap();
        assert!(
            t.apply_point(target).length() < 1e-9,
            "{}",
            t.apply_point(target)
        );
        // A forward-facing row of cameras, all looking along +y: no focus, the median centre.
        let row: Vec<ColmapPose> = (0..5)
            .map(|i| {
                let eye = DVec3::new(i as f64, 0.0, 0.0);
                look_at(eye, eye + DVec3::Y, DVec3::Z)
            })
            .collect();
        let t = SceneTransform::from_poses(&row).unwrap();
        assert!(t.apply_point(DVec3::new(2.0, 0.0, 0.0)).length() < 1e-9);
    }

    #[test]
    fn cameras_at_one_point_are_an_error() {
        let pose = look_at(DVec3::ONE, DVec3::ZERO, DVec3::Z);
        let err = SceneTransform::from_poses(&[pose, pose]).unwrap_err();
        assert!(err.to_string().contains("one point"), "{err}");
        assert!(SceneTransform::from_poses(&[]).is_err());
    }

    #[test]
    fn centres_too_far_from_the_origin_to_resolve_are_an_error() {
        // A ring of radius 4 around (1e13, 0, 0): float64 spaces positions 0.002 apart there
        // (around 1e17, 16 apart: the ring collapses to one point, the error above).
        let ring = |offset: f64| -> Vec<ColmapPose> {
            let centre = DVec3::new(offset, 0.0, 0.0);
            (0..8)
                .map(|i| {
                    let a = i as f64 * std::f64::consts::TAU / 8.0;
                    let eye = centre + 4.0 * DVec3::new(a.cos(), a.sin(), 0.5);
                    look_at(eye, centre, DVec3::Z)
                })
                .collect()
        };
        let err = SceneTransform::from_poses(&ring(1e13))
            .unwrap_err()
            .to_string();
        assert!(err.contains("origin") && err.contains("1e13 from"), "{err}");
        assert!(err.len() < 250, "{err}");
        // A survey's coordinates (metres, 5e5 from the origin) are resolved to 1e-10 m.
        assert!(SceneTransform::from_poses(&ring(5e5)).is_ok());
    }

    #[test]
    fn text_round_trips_exactly_and_bad_text_is_refused() {
        let t = SceneTransform::from_poses(&tilted_ring()).unwrap();
        let text = t.to_text();
        assert_eq!(text.split(' ').count(), 13);
        assert_eq!(SceneTransform::from_text(&text).unwrap(), t);
        assert!(t.agrees_with(&t, 0.0));
        let moved = SceneTransform {
            center: t.center + DVec3::new(0.0, 0.0, 0.01 / t.scale),
            ..t
        };
        assert!(!t.agrees_with(&moved, 1e-3) && t.agrees_with(&moved, 0.02));
        for (bad, says) in [
            ("1 0 0 0 1 0 0 0 1 0 0 0", "12 numbers"),
            ("1 0 0 0 1 0 0 0 1 0 0 0 x", "numbers"),
            ("1 0 0 0 1 0 0 0 1 0 0 0 0", "scale"),
            ("1 0 0 0 1 0 0 0 1 NaN 0 0 1", "finite"),
            ("2 0 0 0 1 0 0 0 1 0 0 0 1", "rotation"),
            ("-1 0 0 0 1 0 0 0 1 0 0 0 1", "rotation"),
        ] {
            let err = SceneTransform::from_text(bad).unwrap_err().to_string();
            assert!(err.contains(says), "{bad}: {err}");
        }
    }

    #[test]
    fn rotation_between_handles_opposite_vectors() {
        for (a, b) in [
            (DVec3::Z, DVec3::Z),
            (DVec3::Z, -DVec3::Z),
            (DVec3::X, DVec3::Y),
        ] {
            let r = rotation_between(a, b);
            assert!((r * a - b).length() < 1e-12);
            assert!((r.determinant() - 1.0).abs() < 1e-12);
        }
    }
}
