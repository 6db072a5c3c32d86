//! Which cameras an LLFF folder's frames take when it also holds a COLMAP model, as LLFF's
//! `imgs2poses.py` leaves a capture (`poses_bounds.npy` beside the `sparse/0` it was written
//! from). `poses_bounds.npy` is that model's summary: one pinhole per photo, no distortion,
//! the focal length shared; the model has each photo's own intrinsics and distortion. So the
//! model is taken when it reads and registers every photo `poses_bounds.npy` lists, and
//! `poses_bounds.npy` otherwise (what was chosen, and why, is one line on stderr). The
//! model's frames keep LLFF's depth bounds (the spiral path's focus depth,
//! [`super::spiral`]) when both place the cameras alike: the same photos, the same centres.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::Result;

use super::capture_frame::CaptureFrames;
use nerf_core::term::error_line;

/// Where an LLFF folder's cameras come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CamerasFrom {
    /// `poses_bounds.npy`.
    PosesBounds,
    /// The COLMAP model beside it.
    ColmapModel,
}

/// The frames of the LLFF capture in `dir`, which also holds a COLMAP model, from `llff`
/// (`poses_bounds.npy` read) or `colmap` (the model read): the model's when it reads and
/// registers every photo, else `poses_bounds.npy`'s; where they came from; and the line that
/// says which and why. An error only when neither reads (the LLFF error: its file is what the
/// folder was detected by).
pub(crate) fn choose_cameras(
    dir: &Path,
    llff: Result<CaptureFrames>,
    colmap: Result<CaptureFrames>,
) -> Result<(CamerasFrom, CaptureFrames, String)> {
    let name = dir
        .file_name()
        .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into());
    match (llff, colmap) {
        (Ok(llff), Ok(mut colmap)) => {
            match unregistered(&llff, &colmap) {
                None => {
                    let bounds = copy_depth_bounds(&llff, &mut colmap);
                    let note =
                        format!(
                    "{name}: cameras from {} (per-frame intrinsics{}), not poses_bounds.npy \
                     ({}){}",
                    colmap.camera_source,
                    if has_distortion(&colmap) { " and distortion" } else { "" },
                    llff_intrinsics(&llff),
                    if bounds {
                        "; its depth bounds kept"
                    } else {
                        ""
                    }
                );
                    Ok((CamerasFrom::ColmapModel, colmap, note))
                }
                Some(missing) => {
                    let note = format!(
                        "{name}: cameras from poses_bounds.npy, not {} (it does not register \
                     {missing})",
                        colmap.camera_source
                    );
                    Ok((CamerasFrom::PosesBounds, llff, note))
                }
            }
        }
        (Err(llff), Ok(colmap)) => {
            let note = format!(
                "{name}: cameras from {}; poses_bounds.npy does not read ({})",
                colmap.camera_source,
                error_line(llff.as_ref())
            );
            Ok((CamerasFrom::ColmapModel, colmap, note))
        }
        (Ok(llff), Err(colmap)) => {
            let note = format!(
                "{name}: cameras from poses_bounds.npy; the COLMAP model beside it does not \
                 read ({})",
                error_line(colmap.as_ref())
            );
            Ok((CamerasFrom::PosesBounds, llff, note))
        }
        // The LLFF error: its file is what the folder was detected by.
        (Err(llff), Err(_)) => Err(llff),
    }
}

/// The first photo of `llff` (by name) that the model `colmap` does not register, and how
/// many it misses in all; `None` when it registers every one.
fn unregistered(llff: &CaptureFrames, colmap: &CaptureFrames) -> Option<String> {
    let registered: std::collections::HashSet<&PathBuf> =
        colmap.frames.iter().map(|f| &f.file_path).collect();
    let missing: Vec<&PathBuf> = llff
        .frames
        .iter()
        .map(|f| &f.file_path)
        .filter(|p| !registered.contains(p))
        .collect();
    let first = missing.first()?;
    Some(format!(
        "{} of the {} photos, {} the first",
        missing.len(),
        llff.frames.len(),
        first.file_name().unwrap_or_default().to_string_lossy()
    ))
}

/// Gives `colmap`'s frames the depth bounds of the same photos in `llff` when both sources
/// list the same photos with their cameras at the same places (to 1e-4 of the
/// cameras' spread: LLFF's rows are the model's poses); whether they were given.
fn copy_depth_bounds(llff: &CaptureFrames, colmap: &mut CaptureFrames) -> bool {
    if llff.frames.len() != colmap.frames.len() {
        return false;
    }
    let by_path: HashMap<&PathBuf, _> = llff.frames.iter().map(|f| (&f.file_path, f)).collect();
    let centres = |frames: &CaptureFrames| -> Vec<glam::DVec3> {
        frames
            .frames
            .iter()
            .map(|f| f.camera.pose.center())
            .collect()
    };
    let spread = {
        let c = centres(llff);
        let mean = c.iter().copied().sum::<glam::DVec3>() / c.len().max(1) as f64;
        c.iter().map(|p| (*p - mean).length()).fold(0.0, f64::max)
    };
    let alike = colmap.frames.iter().all(|f| {
        by_path.get(&f.file_path).is_some_and(|l| {
            l.depth_bounds.is_some()
                && (l.camera.pose.center() - f.camera.pose.center()).length() <= 1e-4 * spread
        })
    });
    if !alike || spread <= 0.0 {
        return false;
    }
    for frame in &mut colmap.frames {
        frame.depth_bounds = by_path[&frame.file_path].depth_bounds;
    }
    true
}

/// Whether any of the model's cameras has lens distortion.
fn has_distortion(colmap: &CaptureFrames) -> bool {
    colmap
        .frames
        .iter()
        .any(|f| f.camera.distortion.coefficients().iter().any(|&c| c != 0.0))
}

/// What LLFF's rows give for intrinsics: one shared focal length, or one per photo.
fn llff_intrinsics(llff: &CaptureFrames) -> &'static str {
    let first = llff.frames.first().map(|f| f.camera.focal);
    match llff.frames.iter().all(|f| Some(f.camera.focal) == first) {
        true => "one shared focal",
        false => "a pinhole per photo, no distortion",
    }
}
