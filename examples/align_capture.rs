//! How well a capture's cameras (a nerfstudio `transforms.json`, e.g. what `nerf process`
//! wrote) recover the true cameras of a benchmark capture: how many registered, and after the
//! best similarity alignment (rotation from the mean of the per-camera rotations, scale and
//! shift by least squares on the centres, as `apps/nerf/tests/process.rs` aligns its 24 views) the
//! largest rotation error and the largest and mean centre errors as fractions of the truth's
//! size. A second line aligns the centres alone by the least-squares similarity (Horn's
//! quaternion method), which is what "centres within X after a similarity alignment" asks.
//! Both alignments are `nerf::core::camera::alignment`'s; the truth readers are
//! `nerf::io::camera_truth`'s. Frames are matched by image stem (`images/r_7.jpg` ↔
//! `train/r_7`). TRUTH is one of:
//!
//! * a NeRF-synthetic scene folder (its `transforms_train.json`): sizes are fractions of the
//!   scene radius, the true cameras' mean distance from the origin;
//! * a Middlebury `*_par.txt` (templeRing): fractions of the ring's radius, the true centres'
//!   mean distance from their mean;
//! * a folder of Strecha `*.camera` files (Herz-Jesu-P25's `gt_dense_cameras`), or a folder
//!   holding `gt_dense_cameras`: fractions of the camera spread, the true centres' RMS
//!   distance from their mean;
//! * a folder holding a COLMAP model (`sparse/N`, as a reference reconstruction, such as the
//!   one beside a capture's `poses_bounds.npy`): fractions of the camera spread.
//!
//! CAPTURE_DIR is a folder with a `transforms.json`, or else a COLMAP model (a model folder,
//! or a folder holding `sparse/N`, as the mapper runs of `nerf process` leave them).
//!
//! Run: `cargo run --release --example align_capture -- TRUTH CAPTURE_DIR`.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{bail, Result};
use glam::{DMat3, DVec3};
use nerf::core::camera::alignment::spread;
use nerf::core::camera::alignment::{
    align_by_orientations, align_centres, CameraAlignment, CameraPair,
};
use nerf::core::camera::ColmapPose;
use nerf::io::camera_truth::{
    image_stem, read_middlebury_par, read_strecha_cameras, read_transforms, TrueCamera,
};

/// The true cameras at `truth`, the size errors are measured in and its name.
fn read_truth(truth: &Path) -> Result<(Vec<TrueCamera>, f64, &'static str)> {
    let mean_distance = |cameras: &[TrueCamera], from: DVec3| {
        cameras.iter().map(|c| c.centre.distance(from)).sum::<f64>() / cameras.len() as f64
    };
    let centres = |cameras: &[TrueCamera]| cameras.iter().map(|c| c.centre).collect::<Vec<_>>();
    let mean =
        |cameras: &[TrueCamera]| centres(cameras).iter().sum::<DVec3>() / cameras.len() as f64;
    if truth.join("transforms_train.json").is_file() {
        let cameras = read_transforms(&truth.join("transforms_train.json"))?;
        let radius = mean_distance(&cameras, DVec3::ZERO);
        return Ok((cameras, radius, "the scene radius"));
    }
    if truth.is_file() && truth.to_string_lossy().ends_with("_par.txt") {
        let cameras = read_middlebury_par(truth)?;
        let radius = mean_distance(&cameras, mean(&cameras));
        return Ok((cameras, radius, "the ring's radius"));
    }
    if nerf::io::colmap::find_model_folder(truth).is_some() {
        let cameras = read_capture(truth)?;
        let size = spread(&centres(&cameras));
        return Ok((cameras, size, "the camera spread"));
    }
    let folder = if truth.join("gt_dense_cameras").is_dir() {
        truth.join("gt_dense_cameras")
    } else {
        truth.to_path_buf()
    };
    if folder.is_dir() {
        let cameras = read_strecha_cameras(&folder)?;
        let size = spread(&centres(&cameras));
        return Ok((cameras, size, "the camera spread"));
    }
    bail!(
        "{}: not a NeRF-synthetic scene, a *_par.txt, a folder of .camera files or a COLMAP model",
        truth.display()
    )
}

/// The cameras of `capture`: its `transforms.json`, else the largest COLMAP model in it.
fn read_capture(capture: &Path) -> Result<Vec<TrueCamera>> {
    let transforms = capture.join("transforms.json");
    if transforms.is_file() {
        return read_transforms(&transforms);
    }
    let (_, model) = nerf::io::colmap::find_model(capture)?;
    model
        .images
        .iter()
        .map(|image| {
            let pose = ColmapPose::from_quaternion(image.qvec, image.tvec)?;
            let m = pose.opengl_camera_to_world();
            let column = |j: usize| DVec3::new(m[0][j], m[1][j], m[2][j]);
            Ok(TrueCamera {
                stem: image_stem(&image.name),
                rotation: DMat3::from_cols(column(0), column(1), column(2)),
                centre: column(3),
            })
        })
        .collect()
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [truth, capture] = &args[..] else {
        bail!("usage: align_capture TRUTH CAPTURE_DIR");
    };
    let (truth, size, size_name) = read_truth(Path::new(truth))?;
    let found = read_capture(Path::new(capture))?;
    let by_stem: HashMap<&str, &TrueCamera> = truth.iter().map(|c| (c.stem.as_str(), c)).collect();
    let mut named: Vec<(&str, CameraPair)> = found
        .iter()
        .filter_map(|f| {
            by_stem.get(f.stem.as_str()).map(|t| {
                let pair = CameraPair {
                    true_rotation: t.rotation,
                    true_centre: t.centre,
                    rotation: f.rotation,
                    centre: f.centre,
                };
                (f.stem.as_str(), pair)
            })
        })
        .collect();
    named.sort_by(|a, b| a.0.cmp(b.0));
    let (names, pairs): (Vec<&str>, Vec<CameraPair>) = named.into_iter().unzip();
    if pairs.len() < 3 {
        bail!("only {} frames match the truth by name", pairs.len());
    }
    let n = pairs.len() as f64;
    let by_orientation = align_by_orientations(&pairs);
    let by_centres = align_centres(&pairs);
    let fractions =
        |a: &CameraAlignment| -> Vec<f64> { a.centre_errors.iter().map(|e| e / size).collect() };
    let (centre_errors, centres_only) = (fractions(&by_orientation), fractions(&by_centres));
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    let over = |v: &[f64]| v.iter().filter(|e| **e > 0.01).count();
    println!(
        "{} of {} registered; rotation error max {:.3} deg; centre error max {:.5}, mean {:.5} of {size_name} ({size:.4})",
        pairs.len(),
        truth.len(),
        max(&by_orientation.rotation_errors_degrees),
        max(&centre_errors),
        centre_errors.iter().sum::<f64>() / n,
    );
    println!(
        "centres aligned alone (least-squares similarity): centre error max {:.5}, mean {:.5} of {size_name}; over 1%: {} (rotation-first alignment: {})",
        max(&centres_only),
        centres_only.iter().sum::<f64>() / n,
        over(&centres_only),
        over(&centre_errors),
    );
    let mut worst: Vec<(f64, &str)> = centres_only.iter().cloned().zip(names).collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    let listed: Vec<String> = worst
        .iter()
        .take(5)
        .map(|(e, name)| format!("{name} {e:.5}"))
        .collect();
    println!("largest centre errors: {}", listed.join(", "));
    Ok(())
}
