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
use super::colmap_scene::COLMAP;
use super::llff::LLFF;
use super::scene_format::FormatRead;
use nerf_core::term::error_line;

/// The frames of the LLFF capture in `dir`: from its COLMAP model when one is there and
/// registers every photo, else from `poses_bounds.npy`; the format the cameras came from; and
/// the line that says which and why when both were there (`None` for a plain LLFF folder).
pub(crate) fn read_llff_folder(dir: &Path) -> Result<FormatRead> {
    let read = |cameras_from, frames, note| FormatRead {
        frames,
        cameras_from,
        note,
    };
    if crate::colmap::find_model_folder(dir).is_none() {
        return Ok(FormatRead::own(LLFF, super::llff::read_frames(dir)?));
    }
    let name = dir
        .file_name()
        .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into());
    let llff = super::llff::read_frames(dir);
    let colmap = super::colmap_scene::read_frames(dir);
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
                    Ok(read(COLMAP, colmap, Some(note)))
                }
                Some(missing) => {
                    let note = format!(
                        "{name}: cameras from poses_bounds.npy, not {} (it does not register \
                     {missing})",
                        colmap.camera_source
                    );
                    Ok(read(LLFF, llff, Some(note)))
                }
            }
        }
        (Err(llff), Ok(colmap)) => {
            let note = format!(
                "{name}: cameras from {}; poses_bounds.npy does not read ({})",
                colmap.camera_source,
                error_line(llff.as_ref())
            );
            Ok(read(COLMAP, colmap, Some(note)))
        }
        (Ok(llff), Err(colmap)) => {
            let note = format!(
                "{name}: cameras from poses_bounds.npy; the COLMAP model beside it does not \
                 read ({})",
                error_line(colmap.as_ref())
            );
            Ok(read(LLFF, llff, Some(note)))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::capture::read_capture_split;
    use crate::dataset::Split;

    /// The real capture bird_handheld (poses_bounds.npy beside its COLMAP model), when it is
    /// on this machine.
    fn bird() -> Option<PathBuf> {
        let dir =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real/bird_handheld");
        let found = dir.join("poses_bounds.npy").is_file() && dir.join("sparse").is_dir();
        if !found {
            eprintln!("skipping: {} not found", dir.display());
        }
        found.then_some(dir)
    }

    #[test]
    fn bird_handheld_takes_its_colmap_model_with_the_same_holdout() {
        let Some(dir) = bird() else { return };
        let FormatRead {
            frames: read,
            cameras_from,
            note,
        } = read_llff_folder(&dir).unwrap();
        assert_eq!(cameras_from, COLMAP);
        let note = note.unwrap();
        assert_eq!(
            note,
            "bird_handheld: cameras from the COLMAP model sparse/0 (per-frame intrinsics), not \
             poses_bounds.npy (one shared focal); its depth bounds kept"
        );
        assert_eq!(read.frames.len(), 184);
        let focals: Vec<f64> = read.frames.iter().map(|f| f.camera.focal[0]).collect();
        let (low, high) = focals
            .iter()
            .fold((f64::INFINITY, 0.0_f64), |(l, h), &f| (l.min(f), h.max(f)));
        assert!(
            low >= 792.5 && high <= 1037.5 && high - low > 200.0,
            "{low} {high}"
        );
        assert!(read.frames.iter().all(|f| f.depth_bounds.is_some()));
        // The split: every 8th of the sorted names, the same photos as poses_bounds.npy's.
        let names = |split: Split, dir: &Path| -> Vec<String> {
            read_capture_split(dir, LLFF, split)
                .unwrap()
                .frames
                .iter()
                .map(|f| f.file_path.file_name().unwrap().to_string_lossy().into())
                .collect()
        };
        let test = names(Split::Test, &dir);
        assert_eq!(test.len(), 23);
        // poses_bounds.npy alone: its photos linked in.
        let alone = tempfile::tempdir().unwrap();
        std::fs::copy(
            dir.join("poses_bounds.npy"),
            alone.path().join("poses_bounds.npy"),
        )
        .unwrap();
        std::os::unix::fs::symlink(dir.join("images"), alone.path().join("images")).unwrap();
        let alone_read = read_llff_folder(alone.path()).unwrap();
        assert_eq!((alone_read.cameras_from, alone_read.note), (LLFF, None));
        assert_eq!(names(Split::Test, alone.path()), test);
        assert_eq!(names(Split::Train, alone.path()), names(Split::Train, &dir));
    }
}
