//! What `nerf process` takes in and leaves behind, checked before COLMAP runs: the photos
//! listed (symbolic links to folders not followed), names COLMAP can round-trip, photos that
//! decode, and `OUT` marked unfinished while a run is under way, so that a failed run leaves
//! `OUT` clearly marked and a re-run starts over (docs/reliability.md#captures).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use nerf::io::progress::progress_bar;

/// The file that marks `OUT` as holding an unfinished run's outputs.
pub const UNFINISHED_MARKER: &str = ".nerf-process-unfinished";

/// The outputs a run writes into `OUT`, which a later run refuses to replace unless the
/// [`UNFINISHED_MARKER`] says they are an unfinished run's.
pub const OUTPUTS: [&str; 3] = ["transforms.json", "images", "colmap"];

/// Extensions of the photos taken (compared without case).
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The photos under `dir` (PNG and JPEG by extension, in subfolders too, hidden entries and
/// `skip` left out) as paths relative to `dir`, sorted. Symbolic links to folders are not
/// followed (a note names the first); links to photos are taken (their target is copied).
/// One-line errors: `dir` not a folder, or no photos in it.
pub fn list_images(dir: &Path, skip: Option<&Path>) -> Result<Vec<PathBuf>> {
    if !dir.is_dir() {
        bail!("--images {}: not a folder", dir.display());
    }
    let mut found = Vec::new();
    let mut skipped_links = Vec::new();
    let mut pending = vec![PathBuf::new()];
    while let Some(relative) = pending.pop() {
        let folder = dir.join(&relative);
        let entries = std::fs::read_dir(&folder)
            .with_context(|| format!("cannot list {}", folder.display()))?;
        for entry in entries {
            let entry = entry.with_context(|| format!("cannot list {}", folder.display()))?;
            let name = entry.file_name();
            if name.to_string_lossy().starts_with('.') {
                continue;
            }
            let path = entry.path();
            let child = relative.join(&name);
            let kind = entry
                .file_type()
                .with_context(|| format!("cannot list {}", folder.display()))?;
            if kind.is_symlink() && path.is_dir() {
                // Not followed: a link back up the tree would list its photos again and again
                // (two such links made the walk exponential).
                skipped_links.push(path);
            } else if kind.is_dir() {
                let skipped = skip.is_some_and(|s| same_file(&path, s));
                if !skipped {
                    pending.push(child);
                }
            } else if path.is_file() && is_image_name(&path) {
                found.push(child);
            }
        }
    }
    if found.is_empty() {
        bail!(
            "no images in {}: nerf process takes PNG and JPEG photos (.png, .jpg, .jpeg), in subfolders too",
            dir.display()
        );
    }
    if let Some(first) = skipped_links.first() {
        log::warn!(
            "note: {} symbolic link{} to folders not followed under {} (the first: {})",
            skipped_links.len(),
            if skipped_links.len() == 1 { "" } else { "s" },
            dir.display(),
            first.display()
        );
    }
    found.sort();
    Ok(found)
}

/// Whether `a` and `b` name the same existing file or folder.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Whether `path` has a photo's extension.
fn is_image_name(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Copies each of `names` (relative to `from`) to the same relative path under `to`, each
/// through a temporary file renamed into place, so no half-copied photo is ever there.
pub fn copy_images(from: &Path, names: &[PathBuf], to: &Path) -> Result<()> {
    let bar = progress_bar(names.len() as u64, "copying images");
    for name in names {
        let target = to.join(name);
        let folder = target.parent().unwrap_or(to);
        std::fs::create_dir_all(folder)
            .with_context(|| format!("cannot create {}", folder.display()))?;
        let file_name = target.file_name().unwrap_or_default().to_string_lossy();
        let temp = folder.join(format!(".{file_name}.{}.tmp", std::process::id()));
        let source = from.join(name);
        let copied = std::fs::copy(&source, &temp).and_then(|_| std::fs::rename(&temp, &target));
        if let Err(e) = copied {
            let _ = std::fs::remove_file(&temp);
            bail!(
                "cannot copy {} to {}: {e}",
                source.display(),
                target.display()
            );
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(())
}

/// An error naming the first photo whose relative path COLMAP cannot round-trip through its
/// text models and databases: a name with a control character (a line break, a tab), a part
/// with leading or trailing white space, or one that is not UTF-8. Refused before anything is
/// copied or run (rename the photo).
pub fn check_names(dir: &Path, names: &[PathBuf]) -> Result<()> {
    for name in names {
        let text = name.to_str().with_context(|| {
            format!(
                "{}: the name is not UTF-8, which COLMAP cannot hold: rename it",
                dir.join(name).display()
            )
        })?;
        let bad_part = name.components().any(|part| {
            let part = part.as_os_str().to_string_lossy();
            part.trim() != part
        });
        if text.chars().any(char::is_control) || bad_part {
            // The name escaped, so that the message stays one line.
            bail!(
                "{}: the photo {text:?} has a name COLMAP cannot keep (a control character such \
                 as a line break, or white space at the start or end of a part): rename it",
                dir.display()
            );
        }
    }
    Ok(())
}

/// An error naming the first of `names` (relative to `dir`) whose header does not decode as
/// an image of positive size, before COLMAP's feature extraction would fail on it.
pub fn check_photos_decode(dir: &Path, names: &[PathBuf]) -> Result<()> {
    for name in names {
        let path = dir.join(name);
        match image::image_dimensions(&path) {
            Ok((w, h)) if w > 0 && h > 0 => {}
            Ok((w, h)) => bail!("{}: a photo of {w}x{h} pixels", path.display()),
            Err(e) => bail!(
                "{}: not a photo that decodes ({}): remove it or convert it",
                path.display(),
                e.to_string().replace('\n', " ")
            ),
        }
    }
    Ok(())
}

/// Prepares `out` for a run: an error when it holds a finished run's outputs (or outputs
/// without the [`UNFINISHED_MARKER`]), else removes an unfinished run's outputs (saying so)
/// and writes the marker, which [`mark_finished`] removes once `transforms.json` is written.
pub fn start_run(out: &Path) -> Result<()> {
    let marker = out.join(UNFINISHED_MARKER);
    let present: Vec<&str> = OUTPUTS
        .into_iter()
        .filter(|name| out.join(name).symlink_metadata().is_ok())
        .collect();
    let unfinished = marker.is_file() && !present.contains(&"transforms.json");
    if !present.is_empty() && !unfinished {
        bail!(
            "{} already holds {} from an earlier run: remove them or choose another --out",
            out.display(),
            present.join(", ")
        );
    }
    if unfinished {
        for name in &present {
            let path = out.join(name);
            let removed = match path.symlink_metadata() {
                Ok(m) if m.is_dir() => std::fs::remove_dir_all(&path),
                _ => std::fs::remove_file(&path),
            };
            removed.with_context(|| format!("cannot remove {}", path.display()))?;
        }
        log::warn!(
            "note: {} held an unfinished run ({}): removed, starting over",
            out.display(),
            if present.is_empty() {
                "nothing written yet".to_string()
            } else {
                present.join(", ")
            }
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(
        &marker,
        "nerf process: unfinished; a re-run removes images/ and colmap/\n",
    )
    .with_context(|| format!("cannot write {}", marker.display()))
}

/// Removes the [`UNFINISHED_MARKER`] of `out` after a run wrote its `transforms.json`.
pub fn mark_finished(out: &Path) -> Result<()> {
    let marker = out.join(UNFINISHED_MARKER);
    std::fs::remove_file(&marker).with_context(|| format!("cannot remove {}", marker.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symlinked_folders_are_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let photos = dir.path().join("photos");
        std::fs::create_dir_all(photos.join("sub")).unwrap();
        std::fs::write(photos.join("a.png"), b"").unwrap();
        std::fs::write(photos.join("sub").join("b.jpg"), b"").unwrap();
        // Two links back up the tree: followed, the walk was exponential.
        std::os::unix::fs::symlink(&photos, photos.join("loop1")).unwrap();
        std::os::unix::fs::symlink(&photos, photos.join("sub").join("loop2")).unwrap();
        let names = list_images(&photos, None).unwrap();
        assert_eq!(names, [PathBuf::from("a.png"), PathBuf::from("sub/b.jpg")]);
    }

    #[test]
    fn names_colmap_cannot_keep_are_refused() {
        let dir = Path::new("/p");
        assert!(check_names(dir, &[PathBuf::from("a b.jpg"), PathBuf::from("x/é.png")]).is_ok());
        for bad in [
            "line\nbreak.jpg",
            " lead.jpg",
            "trail.jpg ",
            "tab\t.png",
            "dir /a.jpg",
        ] {
            let err = check_names(dir, &[PathBuf::from(bad)])
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("rename") && !err.contains('\n'),
                "{bad:?}: {err}"
            );
        }
    }

    #[test]
    fn a_file_that_is_not_a_photo_is_named() {
        let dir = tempfile::tempdir().unwrap();
        image::RgbImage::new(4, 3)
            .save(dir.path().join("good.png"))
            .unwrap();
        std::fs::write(dir.path().join("bad.jpg"), b"not a jpeg at all").unwrap();
        let good = [PathBuf::from("good.png")];
        assert!(check_photos_decode(dir.path(), &good).is_ok());
        let err = check_photos_decode(dir.path(), &[PathBuf::from("bad.jpg")]).unwrap_err();
        assert!(err.to_string().contains("bad.jpg: not a photo"), "{err}");
    }

    #[test]
    fn an_unfinished_run_is_marked_and_a_rerun_starts_over() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        start_run(&out).unwrap();
        assert!(out.join(UNFINISHED_MARKER).is_file());
        // The run fails after writing images/ and colmap/: a re-run clears them.
        std::fs::create_dir_all(out.join("images")).unwrap();
        std::fs::create_dir_all(out.join("colmap").join("sparse")).unwrap();
        start_run(&out).unwrap();
        assert!(!out.join("images").exists() && !out.join("colmap").exists());
        // A finished run is never replaced.
        std::fs::write(out.join("transforms.json"), "{}").unwrap();
        mark_finished(&out).unwrap();
        let err = start_run(&out).unwrap_err().to_string();
        assert!(err.contains("already holds transforms.json"), "{err}");
        // Nor are outputs without the marker (another tool's, or a user's).
        let other = dir.path().join("other");
        std::fs::create_dir_all(other.join("images")).unwrap();
        assert!(start_run(&other).is_err());
        assert!(other.join("images").is_dir());
    }
}
