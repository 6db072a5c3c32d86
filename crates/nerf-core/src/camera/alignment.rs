//! How closely recovered cameras (from structure from motion) match the true ones, up to the
//! similarity (rotation, scale, shift) that a reconstruction's gauge leaves free: the aligning
//! similarity and each camera's rotation and centre error after it. Two alignments:
//!
//! * [`align_by_orientations`]: the rotation from the mean of the per-camera rotations
//!   `R_t·R_rᵀ` (as quaternions, signs made consistent), then scale and shift by least squares
//!   on the centres;
//! * [`align_centres`]: the least-squares similarity of the centres alone (Horn 1987: the
//!   rotation is the unit quaternion that is the largest eigenvector of his 4×4 matrix of the
//!   centred cross-covariance, found here by power iteration on the matrix shifted to be
//!   positive definite), what "centres within X after a similarity alignment" usually means.
//!
//! Written by hand: glam has no eigen-solver, and the rest is a few sums.

use glam::{DMat3, DQuat, DVec3};

/// One camera as recovered and as it truly is: camera-to-world rotations and centres, in
/// any one camera convention shared by both.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPair {
    /// The true camera-to-world rotation.
    pub true_rotation: DMat3,
    /// The true camera centre.
    pub true_centre: DVec3,
    /// The recovered camera-to-world rotation.
    pub rotation: DMat3,
    /// The recovered camera centre.
    pub centre: DVec3,
}

/// A similarity taking recovered cameras to true ones, and each camera's error after it.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraAlignment {
    /// The rotation `A` (recovered → true).
    pub rotation: DMat3,
    /// The scale `s`.
    pub scale: f64,
    /// The shift `b`: a recovered centre `C` goes to `s·A·C + b`.
    pub shift: DVec3,
    /// Per camera, the angle of `R_tᵀ·A·R_r`, degrees.
    pub rotation_errors_degrees: Vec<f64>,
    /// Per camera, `|s·A·C_r + b − C_t|`, in the true cameras' units.
    pub centre_errors: Vec<f64>,
}

/// The angle of a rotation matrix, degrees.
pub(crate) fn rotation_angle_degrees(r: DMat3) -> f64 {
    ((r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// The alignment whose rotation is the mean of the per-camera rotations (see the module).
/// `pairs` must not be empty.
pub fn align_by_orientations(pairs: &[CameraPair]) -> CameraAlignment {
    let per_camera = |p: &CameraPair| DQuat::from_mat3(&(p.true_rotation * p.rotation.transpose()));
    let q0 = per_camera(&pairs[0]);
    let sum = pairs
        .iter()
        .fold(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0), |s, p| {
            let q = per_camera(p);
            s + if q.dot(q0) < 0.0 { -q } else { q }
        });
    with_rotation(pairs, DMat3::from_quat(sum.normalize()))
}

/// The least-squares similarity of the centres alone (Horn's method, see the module).
/// `pairs` must not be empty.
pub fn align_centres(pairs: &[CameraPair]) -> CameraAlignment {
    let (mean_t, mean_r) = means(pairs);
    // s[a][b] = Σ r'_a t'_b over the centred centres.
    let mut s = [[0.0f64; 3]; 3];
    for p in pairs {
        let (r, t) = (
            (p.centre - mean_r).to_array(),
            (p.true_centre - mean_t).to_array(),
        );
        for (a, row) in s.iter_mut().enumerate() {
            for (b, v) in row.iter_mut().enumerate() {
                *v += r[a] * t[b];
            }
        }
    }
    let [[xx, xy, xz], [yx, yy, yz], [zx, zy, zz]] = s;
    let m = [
        [xx + yy + zz, yz - zy, zx - xz, xy - yx],
        [yz - zy, xx - yy - zz, xy + yx, zx + xz],
        [zx - xz, xy + yx, -xx + yy - zz, yz + zy],
        [xy - yx, zx + xz, yz + zy, -xx - yy + zz],
    ];
    let shift: f64 = m.iter().flatten().map(|v| v.abs()).sum::<f64>().max(1e-300);
    let mut q = [1.0, 0.1, 0.1, 0.1];
    for _ in 0..10_000 {
        let mut next = [0.0; 4];
        for (i, n) in next.iter_mut().enumerate() {
            *n = shift * q[i] + (0..4).map(|j| m[i][j] * q[j]).sum::<f64>();
        }
        let norm = next.iter().map(|v| v * v).sum::<f64>().sqrt();
        q = next.map(|v| v / norm);
    }
    let rotation = DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize());
    with_rotation(pairs, rotation)
}

/// The mean true and recovered centres.
fn means(pairs: &[CameraPair]) -> (DVec3, DVec3) {
    let n = pairs.len() as f64;
    (
        pairs.iter().map(|p| p.true_centre).sum::<DVec3>() / n,
        pairs.iter().map(|p| p.centre).sum::<DVec3>() / n,
    )
}

/// Scale and shift by least squares on the centres for the given rotation, and the errors.
fn with_rotation(pairs: &[CameraPair], rotation: DMat3) -> CameraAlignment {
    let (mean_t, mean_r) = means(pairs);
    let (num, den) = pairs.iter().fold((0.0, 0.0), |(num, den), p| {
        let (dt, dr) = (p.true_centre - mean_t, rotation * (p.centre - mean_r));
        (num + dt.dot(dr), den + dr.length_squared())
    });
    let scale = if den > 0.0 { num / den } else { 1.0 };
    let shift = mean_t - scale * (rotation * mean_r);
    CameraAlignment {
        rotation,
        scale,
        shift,
        rotation_errors_degrees: pairs
            .iter()
            .map(|p| rotation_angle_degrees(p.true_rotation.transpose() * rotation * p.rotation))
            .collect(),
        centre_errors: pairs
            .iter()
            .map(|p| (scale * (rotation * p.centre) + shift - p.true_centre).length())
            .collect(),
    }
}

/// The RMS distance of `centres` from their mean.
pub fn spread(centres: &[DVec3]) -> f64 {
    if centres.is_empty() {
        return 0.0;
    }
    let n = centres.len() as f64;
    let mean = centres.iter().copied().sum::<DVec3>() / n;
    (centres
        .iter()
        .map(|c| c.distance_squared(mean))
        .sum::<f64>()
        / n)
        .sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Twelve cameras on a ring, and the same seen through the similarity `C_r = (Aᵀ(C_t − b))/s`,
    /// `R_r = Aᵀ·R_t`, with centre noise `noise` on camera 3.
    fn cameras(noise: f64) -> (Vec<CameraPair>, DMat3, f64, DVec3) {
        let a = DMat3::from_quat(DQuat::from_axis_angle(
            DVec3::new(1.0, 2.0, -0.5).normalize(),
            1.1,
        ));
        let (s, b) = (2.5, DVec3::new(0.3, -1.0, 4.0));
        let pairs = (0..12)
            .map(|i| {
                let phi = i as f64 * 0.5;
                let true_centre =
                    DVec3::new(4.0 * phi.cos(), 4.0 * phi.sin(), 1.0 + 0.1 * i as f64);
                let true_rotation =
                    DMat3::from_quat(DQuat::from_rotation_z(phi) * DQuat::from_rotation_x(0.3));
                let mut centre = a.transpose() * (true_centre - b) / s;
                if i == 3 {
                    centre.x += noise;
                }
                CameraPair {
                    true_rotation,
                    true_centre,
                    rotation: a.transpose() * true_rotation,
                    centre,
                }
            })
            .collect();
        (pairs, a, s, b)
    }

    #[test]
    fn both_alignments_recover_an_exact_similarity() {
        let (pairs, a, s, b) = cameras(0.0);
        for alignment in [align_by_orientations(&pairs), align_centres(&pairs)] {
            assert!((alignment.scale - s).abs() < 1e-9, "{}", alignment.scale);
            assert!((alignment.shift - b).length() < 1e-9);
            // acos near 1 loses half the digits: 1e-4 degrees is about 1.7e-6 rad.
            assert!(rotation_angle_degrees(alignment.rotation.transpose() * a) < 1e-4);
            assert!(alignment.centre_errors.iter().all(|e| *e < 1e-9));
            assert!(alignment.rotation_errors_degrees.iter().all(|e| *e < 1e-4));
        }
    }

    #[test]
    fn the_centre_alignment_fits_the_centres_no_worse_than_the_orientation_one() {
        let (pairs, ..) = cameras(0.2);
        let sum_sq = |a: &CameraAlignment| a.centre_errors.iter().map(|e| e * e).sum::<f64>();
        let (by_orientation, by_centres) = (align_by_orientations(&pairs), align_centres(&pairs));
        assert!(sum_sq(&by_centres) <= sum_sq(&by_orientation) + 1e-12);
        // The moved camera carries the largest error in both.
        for a in [by_orientation, by_centres] {
            let worst = (0..12).max_by(|&i, &j| a.centre_errors[i].total_cmp(&a.centre_errors[j]));
            assert_eq!(worst, Some(3));
        }
        assert!(
            (rotation_angle_degrees(DMat3::from_rotation_z(0.5)) - 0.5f64.to_degrees()).abs()
                < 1e-9
        );
    }
}
