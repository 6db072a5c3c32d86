//! How well a capture's cameras (a nerfstudio `transforms.json`, e.g. what `nerf process`
//! wrote) recover the true cameras of a NeRF-synthetic scene's training views: how many
//! registered, and after the best similarity alignment (rotation from the mean of the
//! per-camera rotations, scale and shift by least squares on the centres, as
//! `tests/process.rs` aligns its 24 views) the largest rotation error and the largest and
//! mean centre errors as fractions of the scene radius (the true cameras' mean distance from
//! the origin). Frames are matched by image name stem (`images/r_7.jpg` ↔ `train/r_7`).
//! A second line aligns the centres alone by the least-squares similarity (Horn's quaternion
//! method, written out below: the largest eigenvector of a 4×4 matrix by power iteration),
//! which is what "centres within X after a similarity alignment" asks.
//!
//! Run: `cargo run --release --example align_capture -- LEGO_DIR CAPTURE_DIR`.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{bail, Context, Result};
use glam::{DMat3, DQuat, DVec3};

/// Image stem → (OpenGL camera → world rotation, centre) of `json`'s frames.
fn cameras(json: &serde_json::Value) -> Result<HashMap<String, (DMat3, DVec3)>> {
    let frames = json["frames"].as_array().context("no frames")?;
    frames
        .iter()
        .map(|f| {
            let path = f["file_path"].as_str().context("file_path missing")?;
            let name = path.rsplit('/').next().unwrap_or(path);
            let stem = name.split('.').next().unwrap_or(name).to_string();
            let m = &f["transform_matrix"];
            let at = |i: usize, j: usize| m[i][j].as_f64().unwrap_or(f64::NAN);
            let column = |j: usize| DVec3::new(at(0, j), at(1, j), at(2, j));
            let rotation = DMat3::from_cols(column(0), column(1), column(2));
            Ok((stem, (rotation, column(3))))
        })
        .collect()
}

fn read_json(path: &Path) -> Result<serde_json::Value> {
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    Ok(serde_json::from_str(&text)?)
}

/// The angle of a rotation matrix, degrees.
fn angle_degrees(r: DMat3) -> f64 {
    ((r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [lego, capture] = &args[..] else {
        bail!("usage: align_capture LEGO_DIR CAPTURE_DIR");
    };
    let truth = cameras(&read_json(&Path::new(lego).join("transforms_train.json"))?)?;
    let found = cameras(&read_json(&Path::new(capture).join("transforms.json"))?)?;
    let mut pairs: Vec<(DMat3, DVec3, DMat3, DVec3)> = found
        .iter()
        .filter_map(|(stem, (rr, cr))| truth.get(stem).map(|(rt, ct)| (*rt, *ct, *rr, *cr)))
        .collect();
    pairs.sort_by(|a, b| a.1.x.total_cmp(&b.1.x));
    if pairs.len() < 3 {
        bail!("only {} frames match the truth by name", pairs.len());
    }
    // True (t) against recovered (r): R_t = A·R_r for one rotation A; C_t = s·A·C_r + b.
    let q0 = DQuat::from_mat3(&(pairs[0].0 * pairs[0].2.transpose()));
    let sum = pairs
        .iter()
        .fold(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0), |s, p| {
            let q = DQuat::from_mat3(&(p.0 * p.2.transpose()));
            s + if q.dot(q0) < 0.0 { -q } else { q }
        });
    let a = DMat3::from_quat(sum.normalize());
    let rotation_errors: Vec<f64> = pairs
        .iter()
        .map(|(rt, _, rr, _)| angle_degrees(rt.transpose() * a * *rr))
        .collect();
    let n = pairs.len() as f64;
    let mean_t = pairs.iter().map(|p| p.1).sum::<DVec3>() / n;
    let mean_r = pairs.iter().map(|p| a * p.3).sum::<DVec3>() / n;
    let (num, den) = pairs.iter().fold((0.0, 0.0), |(num, den), p| {
        let (dt, dr) = (p.1 - mean_t, a * p.3 - mean_r);
        (num + dt.dot(dr), den + dr.length_squared())
    });
    let s = num / den;
    let radius = truth.values().map(|(_, c)| c.length()).sum::<f64>() / truth.len() as f64;
    let centre_errors: Vec<f64> = pairs
        .iter()
        .map(|p| (s * (a * p.3 - mean_r) + mean_t - p.1).length() / radius)
        .collect();
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    let centres_only = horn_errors(&pairs, radius);
    let over = |v: &[f64]| v.iter().filter(|e| **e > 0.01).count();
    println!(
        "{} of {} registered; rotation error max {:.3} deg; centre error max {:.5}, mean {:.5} of the scene radius ({radius:.3})",
        pairs.len(),
        truth.len(),
        max(&rotation_errors),
        max(&centre_errors),
        centre_errors.iter().sum::<f64>() / n,
    );
    println!(
        "centres aligned alone (least-squares similarity): centre error max {:.5}, mean {:.5} of the scene radius; over 1%: {} (rotation-first alignment: {})",
        max(&centres_only),
        centres_only.iter().sum::<f64>() / n,
        over(&centres_only),
        over(&centre_errors),
    );
    Ok(())
}

/// Per camera, `|s·R·C_r + b − C_t| / radius` for the similarity `(s, R, b)` that minimises
/// the squared centre distances (Horn 1987: `R` from the unit quaternion that is the largest
/// eigenvector of his 4×4 matrix of the centred cross-covariance).
fn horn_errors(pairs: &[(DMat3, DVec3, DMat3, DVec3)], radius: f64) -> Vec<f64> {
    let n = pairs.len() as f64;
    let mean_t = pairs.iter().map(|p| p.1).sum::<DVec3>() / n;
    let mean_r = pairs.iter().map(|p| p.3).sum::<DVec3>() / n;
    // s[a][b] = Σ r'_a t'_b.
    let mut s = [[0.0f64; 3]; 3];
    for p in pairs {
        let (r, t) = ((p.3 - mean_r).to_array(), (p.1 - mean_t).to_array());
        for a in 0..3 {
            for b in 0..3 {
                s[a][b] += r[a] * t[b];
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
    // Shifted to be positive definite, so power iteration finds the largest eigenvalue.
    let shift: f64 = m.iter().flatten().map(|v| v.abs()).sum();
    let mut q = [1.0, 0.1, 0.1, 0.1];
    for _ in 0..10_000 {
        let mut next = [0.0; 4];
        for i in 0..4 {
            next[i] = shift * q[i] + (0..4).map(|j| m[i][j] * q[j]).sum::<f64>();
        }
        let norm = next.iter().map(|v| v * v).sum::<f64>().sqrt();
        q = next.map(|v| v / norm);
    }
    let rotation = DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize());
    let (num, den) = pairs.iter().fold((0.0, 0.0), |(num, den), p| {
        let (dt, dr) = (p.1 - mean_t, rotation * (p.3 - mean_r));
        (num + dt.dot(dr), den + dr.length_squared())
    });
    let scale = num / den;
    pairs
        .iter()
        .map(|p| (scale * (rotation * (p.3 - mean_r)) + mean_t - p.1).length() / radius)
        .collect()
}
