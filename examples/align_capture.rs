//! How well a capture's cameras (a nerfstudio `transforms.json`, e.g. what `nerf process`
//! wrote) recover the true cameras of a NeRF-synthetic scene's training views: how many
//! registered, and after the best similarity alignment (rotation from the mean of the
//! per-camera rotations, scale and shift by least squares on the centres, as
//! `tests/process.rs` aligns its 24 views) the largest rotation error and the largest and
//! mean centre errors as fractions of the scene radius (the true cameras' mean distance from
//! the origin). Frames are matched by image name stem (`images/r_7.jpg` ↔ `train/r_7`).
//! A second line aligns the centres alone by the least-squares similarity (Horn's quaternion
//! method), which is what "centres within X after a similarity alignment" asks. Both
//! alignments are `nerf::core::camera_alignment`'s.
//!
//! Run: `cargo run --release --example align_capture -- LEGO_DIR CAPTURE_DIR`.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{bail, Context, Result};
use glam::{DMat3, DVec3};
use nerf::core::camera_alignment::{
    align_by_orientations, align_centres, CameraAlignment, CameraPair,
};

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

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [lego, capture] = &args[..] else {
        bail!("usage: align_capture LEGO_DIR CAPTURE_DIR");
    };
    let truth = cameras(&read_json(&Path::new(lego).join("transforms_train.json"))?)?;
    let found = cameras(&read_json(&Path::new(capture).join("transforms.json"))?)?;
    let mut named: Vec<(&String, CameraPair)> = found
        .iter()
        .filter_map(|(stem, (rotation, centre))| {
            truth.get(stem).map(|(true_rotation, true_centre)| {
                let pair = CameraPair {
                    true_rotation: *true_rotation,
                    true_centre: *true_centre,
                    rotation: *rotation,
                    centre: *centre,
                };
                (stem, pair)
            })
        })
        .collect();
    named.sort_by(|a, b| a.0.cmp(b.0));
    let (names, pairs): (Vec<&String>, Vec<CameraPair>) = named.into_iter().unzip();
    if pairs.len() < 3 {
        bail!("only {} frames match the truth by name", pairs.len());
    }
    let radius = truth.values().map(|(_, c)| c.length()).sum::<f64>() / truth.len() as f64;
    let n = pairs.len() as f64;
    let by_orientation = align_by_orientations(&pairs);
    let by_centres = align_centres(&pairs);
    let fractions =
        |a: &CameraAlignment| -> Vec<f64> { a.centre_errors.iter().map(|e| e / radius).collect() };
    let (centre_errors, centres_only) = (fractions(&by_orientation), fractions(&by_centres));
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    let over = |v: &[f64]| v.iter().filter(|e| **e > 0.01).count();
    println!(
        "{} of {} registered; rotation error max {:.3} deg; centre error max {:.5}, mean {:.5} of the scene radius ({radius:.3})",
        pairs.len(),
        truth.len(),
        max(&by_orientation.rotation_errors_degrees),
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
    let mut worst: Vec<(f64, &String)> = centres_only.iter().cloned().zip(names).collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    let listed: Vec<String> = worst
        .iter()
        .take(5)
        .map(|(e, name)| format!("{name} {e:.5}"))
        .collect();
    println!("largest centre errors: {}", listed.join(", "));
    Ok(())
}
