//! The one rule for writing an output file (images, GIFs, npy arrays, PLY, checkpoints, JSON,
//! reports, logs), so that no write replaces what the user did not mean to replace:
//!
//! * a path that does not exist, or names a regular file, is written beside its real target
//!   (a temporary `.<name>.<pid>.<n>.tmp` in the same directory, unique per process and call)
//!   and renamed over it once complete and synced: an interrupted or failed write leaves the
//!   old file whole;
//! * a symbolic link is followed, to its final target (dangling links included): the
//!   temporary file is written beside that target and renamed over it, so the link stays a
//!   link and the file it points to is updated;
//! * a character device or FIFO (`/dev/null`, `/dev/stdout`, a named pipe) is written
//!   directly: that is what the user meant, and it stays a device;
//! * a directory, socket or block device is refused with one line, and nothing is written;
//! * no temporary file is left behind by any failure: an error or a panic in the writing
//!   closure, a failed sync or rename (a guard removes it), or a second Ctrl-C
//!   ([`exit_removing_temp_files`]). Only SIGKILL can leave one, and the next run removes it
//!   ([`remove_stale_temp_files`]).
//!
//! Appended files (the training log) follow links too; [`open_append`] refuses anything but a
//! regular file.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

use anyhow::{bail, Context, Result};

/// Temporary files being written now, removed by [`exit_removing_temp_files`]. Created,
/// renamed and removed under this lock, so an exit never races a half-made one.
static IN_FLIGHT: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Numbers each temporary file of this process.
static CALLS: AtomicU64 = AtomicU64::new(0);

fn in_flight() -> MutexGuard<'static, Vec<PathBuf>> {
    IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner())
}

/// Milliseconds every atomic write waits between writing its temporary file and renaming it
/// (0, none, unless [`set_write_delay_for_tests`] set it).
static WRITE_DELAY_MS: AtomicU64 = AtomicU64::new(0);

/// Fault injection for the interrupted-training tests: every atomic write from now on waits
/// `ms` milliseconds between writing its temporary file and renaming it, so that a kill is
/// likely to land mid-write (the `nerf` command reads it from `NERF_FAULT_WRITE_DELAY_MS`).
pub fn set_write_delay_for_tests(ms: u64) {
    WRITE_DELAY_MS.store(ms, Ordering::Relaxed);
}

fn fault_injection_pause() {
    let ms = WRITE_DELAY_MS.load(Ordering::Relaxed);
    if ms > 0 {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

/// Where a write to a path goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Target {
    /// A regular file (or none yet) at this real path: temp file beside it, then rename.
    Replace(PathBuf),
    /// A character device or FIFO: written directly.
    Direct(PathBuf),
}

/// `path` with every symbolic link followed to the final target, for a path that does not
/// exist (a dangling link names the file to create).
fn follow_links(path: &Path) -> Result<PathBuf> {
    let mut p = path.to_path_buf();
    for _ in 0..40 {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let to = std::fs::read_link(&p)
                    .with_context(|| format!("cannot write {}", path.display()))?;
                p = match p.parent() {
                    Some(dir) if to.is_relative() => dir.join(to),
                    _ => to,
                };
            }
            _ => return Ok(p),
        }
    }
    bail!(
        "cannot write {}: too many levels of symbolic links",
        path.display()
    )
}

/// Where a write to `path` goes under the module's rule; an error (one line) for a directory,
/// socket or block device, or a path with no file name.
pub(crate) fn target(path: &Path) -> Result<Target> {
    let cannot = || format!("cannot write {}", path.display());
    // The kernel follows the links (`/dev/stdout`'s `/proc/self/fd/1` to a pipe included).
    let real = match std::fs::metadata(path) {
        Ok(m) if m.is_file() => std::fs::canonicalize(path).with_context(cannot)?,
        Ok(m) if m.file_type().is_char_device() || m.file_type().is_fifo() => {
            return Ok(Target::Direct(path.to_path_buf()))
        }
        Ok(m) => bail!(
            "cannot write {}: it is {}, not a file",
            path.display(),
            crate::bounded_read::file_kind(m.file_type())
        ),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => follow_links(path)?,
        Err(e) => bail!("cannot write {}: {e}", path.display()),
    };
    if real.file_name().is_none() {
        bail!("cannot write {}: not a file path", path.display());
    }
    Ok(Target::Replace(real))
}

/// A temporary file beside its target, removed on drop unless renamed into place.
struct TempFile {
    path: PathBuf,
    live: bool,
}

impl TempFile {
    /// A new, unique, empty temporary file for `real` (opened for writing), or for the
    /// path-taking writers none opened.
    fn create(real: &Path) -> std::io::Result<(Self, File)> {
        let dir = real
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let name = real.file_name().unwrap_or_default().to_string_lossy();
        let n = CALLS.fetch_add(1, Ordering::Relaxed);
        let path = dir.join(format!(".{name}.{}.{n}.tmp", std::process::id()));
        let mut live = in_flight();
        // create_new: never through a link someone planted at the temporary name.
        let file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)?;
        live.push(path.clone());
        drop(live);
        // Keep an existing file's permissions.
        if let Ok(m) = std::fs::metadata(real) {
            let _ = file.set_permissions(m.permissions());
        }
        Ok((TempFile { path, live: true }, file))
    }

    /// Renames the temporary file over `real`.
    fn commit(mut self, real: &Path) -> std::io::Result<()> {
        let mut live = in_flight();
        std::fs::rename(&self.path, real)?;
        live.retain(|p| p != &self.path);
        self.live = false;
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if self.live {
            let mut live = in_flight();
            let _ = std::fs::remove_file(&self.path);
            live.retain(|p| p != &self.path);
        }
    }
}

/// Removes every temporary file being written now and exits with `code` at once (a second
/// Ctrl-C). Writes that are under way never complete: their targets keep their old content.
pub fn exit_removing_temp_files(code: i32) -> ! {
    // Held until the process ends: no new temporary file is made, none is renamed.
    let live = in_flight();
    for p in live.iter() {
        let _ = std::fs::remove_file(p);
    }
    std::process::exit(code)
}

/// Runs `write` on the output `path` under the module's rule: on a temp file beside the real
/// target, then synced and renamed over it; directly on a character device or FIFO. On error
/// (or panic) in `write` the temp file is removed and `path` is untouched.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    let cannot = || format!("cannot write {}", path.display());
    match target(path)? {
        Target::Direct(real) => {
            let file = OpenOptions::new()
                .write(true)
                .open(&real)
                .with_context(cannot)?;
            let mut w = BufWriter::new(file);
            write(&mut w).with_context(cannot)?;
            w.flush().with_context(cannot)
        }
        Target::Replace(real) => {
            // What a killed earlier writer of this file left (its process is gone).
            remove_stale_temp_files(&real);
            let (tmp, file) = TempFile::create(&real).with_context(cannot)?;
            let mut w = BufWriter::new(file);
            write(&mut w).with_context(cannot)?;
            w.flush().with_context(cannot)?;
            w.into_inner()
                .map_err(|e| e.into_error())
                .and_then(|f| f.sync_all())
                .with_context(cannot)?;
            fault_injection_pause();
            tmp.commit(&real).with_context(cannot)
        }
    }
}

/// Like [`write_atomically`] for a writer that takes a path (an external program such as
/// ffmpeg): `write` fills the file at the path it is given (a temporary file beside the
/// target, or the device itself), which is then renamed over `path`.
pub fn write_through_path(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let cannot = || format!("cannot write {}", path.display());
    match target(path)? {
        Target::Direct(real) => write(&real),
        Target::Replace(real) => {
            remove_stale_temp_files(&real);
            let (tmp, file) = TempFile::create(&real).with_context(cannot)?;
            drop(file);
            write(&tmp.path)?;
            File::open(&tmp.path)
                .and_then(|f| f.sync_all())
                .with_context(cannot)?;
            tmp.commit(&real).with_context(cannot)
        }
    }
}

/// Writes `text` to `path` atomically.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomically(path, |w| {
        w.write_all(text.as_bytes())?;
        Ok(())
    })
}

/// Opens `path` for appending (created when missing; a link is followed), for a log. An
/// error (one line) when it is a directory, device, FIFO or socket.
pub fn open_append(path: &Path) -> Result<File> {
    if let Ok(m) = std::fs::metadata(path) {
        if !m.is_file() {
            bail!(
                "cannot append to {}: it is {}, not a file",
                path.display(),
                crate::bounded_read::file_kind(m.file_type())
            );
        }
    }
    OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .with_context(|| format!("cannot append to {}", path.display()))
}

/// Removes the file `path` names (through a link, its target: the link stays, and the next
/// write through it makes the file again); a missing file is fine. An error for anything but
/// a regular file.
pub fn remove_output(path: &Path) -> Result<()> {
    let real = match target(path)? {
        Target::Replace(real) => real,
        Target::Direct(_) => bail!("cannot remove {}: it is a device", path.display()),
    };
    match std::fs::remove_file(&real) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("cannot remove {}", path.display()))
        }
        _ => Ok(()),
    }
}

/// Whether process `pid` is running (so its temporary files are in use).
fn alive(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
}

/// Removes temporary files that [`write_atomically`] left beside `path`'s real target when a
/// process was killed mid-write (`.<name>.<pid>[.<n>].tmp` of a process no longer running).
/// The file at `path` itself is never touched: it is always a complete old or new version.
pub fn remove_stale_temp_files(path: &Path) {
    let Ok(Target::Replace(real)) = target(path) else {
        return;
    };
    let dir = real
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let Some(name) = real.file_name().map(|n| n.to_string_lossy().to_string()) else {
        return;
    };
    let prefix = format!(".{name}.");
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().to_string();
        let Some(middle) = file
            .strip_prefix(&prefix)
            .and_then(|r| r.strip_suffix(".tmp"))
        else {
            continue;
        };
        let mut parts = middle.split('.');
        let pid = parts.next().and_then(|p| p.parse::<u32>().ok());
        let rest_ok = parts.all(|p| !p.is_empty() && p.chars().all(|c| c.is_ascii_digit()));
        if let (Some(pid), true) = (pid, rest_ok) {
            if pid != std::process::id() && !alive(pid) {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
}

/// Creates `dir` (and parents) and checks that it is writable, with an error that names it.
pub fn prepare_out_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create output directory {}", dir.display()))?;
    let probe = dir.join(format!(
        ".nerf-write-test.{}.{}",
        std::process::id(),
        CALLS.fetch_add(1, Ordering::Relaxed)
    ));
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| format!("output directory {} is not writable", dir.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_link_stays_a_link_and_its_target_is_updated() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("real")).unwrap();
        std::fs::write(d.join("real/mesh.ply"), "old").unwrap();
        std::os::unix::fs::symlink("real/mesh.ply", d.join("link.ply")).unwrap();
        // A link to a link, and a dangling one: the file is made where it points.
        std::os::unix::fs::symlink("link.ply", d.join("link2.ply")).unwrap();
        std::os::unix::fs::symlink("real/new.ply", d.join("dangling.ply")).unwrap();
        write_text(&d.join("link2.ply"), "new").unwrap();
        write_text(&d.join("dangling.ply"), "made").unwrap();
        for link in ["link.ply", "link2.ply", "dangling.ply"] {
            let m = std::fs::symlink_metadata(d.join(link)).unwrap();
            assert!(m.file_type().is_symlink(), "{link}");
        }
        assert_eq!(
            std::fs::read_to_string(d.join("real/mesh.ply")).unwrap(),
            "new"
        );
        assert_eq!(
            std::fs::read_to_string(d.join("real/new.ply")).unwrap(),
            "made"
        );
        assert_eq!(names(&d.join("real")), ["mesh.ply", "new.ply"]);
        assert_eq!(names(d), ["dangling.ply", "link.ply", "link2.ply", "real"]);
    }

    #[test]
    fn a_character_device_is_written_directly_and_stays_one() {
        let null = Path::new("/dev/null");
        // Checked before writing: a wrong rule would replace the machine's /dev/null.
        assert_eq!(target(null).unwrap(), Target::Direct(null.to_path_buf()));
        write_text(null, "discarded").unwrap();
        write_atomically(null, |w| Ok(w.write_all(&[0u8; 100_000])?)).unwrap();
        assert!(std::fs::metadata(null)
            .unwrap()
            .file_type()
            .is_char_device());
    }

    #[test]
    fn a_fifo_is_written_directly_and_stays_one() {
        let (dir, fifo) = crate::test_files::temp_file("pipe");
        crate::bounded_read::make_fifo(&fifo);
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read_to_string(fifo).unwrap())
        };
        write_text(&fifo, "through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), "through the pipe");
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(names(dir.path()), ["pipe"]);
    }

    #[test]
    fn a_directory_is_refused_and_nothing_is_written() {
        let (dir, sub) = crate::test_files::temp_file("out.png");
        std::fs::create_dir(&sub).unwrap();
        let err = write_text(&sub, "x").unwrap_err().to_string();
        assert!(err.contains("is a directory"), "{err}");
        assert_eq!(err.lines().count(), 1);
        // Through a link too.
        std::os::unix::fs::symlink(&sub, dir.path().join("link")).unwrap();
        assert!(write_text(&dir.path().join("link"), "x").is_err());
        assert!(names(&sub).is_empty());
        assert_eq!(names(dir.path()), ["link", "out.png"]);
        let err = open_append(&sub).unwrap_err().to_string();
        assert!(err.contains("is a directory"), "{err}");
        assert!(open_append(Path::new("/dev/null")).is_err());
    }

    #[test]
    fn no_temporary_file_is_left_by_an_error_a_panic_or_a_failed_rename() {
        let (dir, path) = crate::test_files::temp_file("x.png");
        std::fs::write(&path, "old").unwrap();
        let r = write_atomically(&path, |w| {
            w.write_all(b"partial")?;
            bail!("boom")
        });
        assert_eq!(
            format!("{:#}", r.unwrap_err()),
            format!("cannot write {}: boom", path.display())
        );
        let r = std::panic::catch_unwind(|| {
            write_atomically(&path, |w| {
                w.write_all(b"partial").unwrap();
                panic!("boom")
            })
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old");
        assert_eq!(names(dir.path()), ["x.png"]);
        // A rename that fails: a directory appears at the target while the file is written.
        let late = dir.path().join("late");
        let err = write_atomically(&late, |w| {
            std::fs::create_dir(&late)?;
            std::fs::write(late.join("inside"), "")?;
            Ok(w.write_all(b"data")?)
        })
        .unwrap_err();
        assert!(format!("{err:#}").contains("cannot write"), "{err:#}");
        assert_eq!(names(dir.path()), ["late", "x.png"]);
        // Nothing of this test's is still listed for removal (other tests running beside it
        // may have writes of their own in flight).
        assert!(in_flight().iter().all(|p| !p.starts_with(dir.path())));
    }

    #[test]
    fn temporary_names_are_unique_per_call() {
        let (dir, path) = crate::test_files::temp_file("a.json");
        // A write of the same file inside another: each has its own temporary file.
        write_atomically(&path, |outer| {
            write_text(&path, "inner")?;
            Ok(outer.write_all(b"outer")?)
        })
        .unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "outer");
        assert_eq!(names(dir.path()), ["a.json"]);
    }

    #[test]
    fn a_path_taking_writer_fills_a_temporary_file_that_is_renamed() {
        let (dir, path) = crate::test_files::temp_file("camera_path.mp4");
        std::fs::write(&path, "old").unwrap();
        let mut seen = PathBuf::new();
        write_through_path(&path, |tmp| {
            seen = tmp.to_path_buf();
            Ok(std::fs::write(tmp, "encoded")?)
        })
        .unwrap();
        assert_ne!(seen, path);
        assert_eq!(seen.parent(), Some(dir.path()));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "encoded");
        // A failing program: the old file stays, and its partial output is removed.
        let r = write_through_path(&path, |tmp| {
            std::fs::write(tmp, "partial")?;
            bail!("ffmpeg failed")
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "encoded");
        assert_eq!(names(dir.path()), ["camera_path.mp4"]);
    }

    #[test]
    fn a_write_removes_what_a_killed_writer_left_and_its_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let path = d.join("m.ply");
        // A writer killed mid-write (a dead pid) left its temporary file.
        std::fs::write(d.join(".m.ply.2000000000.1.tmp"), "half").unwrap();
        write_atomically(&path, |w| Ok(w.write_all(b"whole")?)).unwrap();
        assert_eq!(names(d), vec!["m.ply".to_string()]);
        // A failing writer's error (a full disk, say) says which file it was writing.
        let err = write_atomically(&path, |_| {
            Err(std::io::Error::from_raw_os_error(libc::EFBIG).into())
        })
        .unwrap_err();
        let err = format!("{err:#}");
        assert!(
            err.contains("cannot write") && err.contains("m.ply"),
            "{err}"
        );
        assert_eq!(std::fs::read(&path).unwrap(), b"whole");
    }

    #[test]
    fn stale_temporary_files_of_dead_processes_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let path = d.join("m.safetensors");
        let own = std::process::id();
        for name in [
            // Dead processes (pids past Linux's largest), old and new naming.
            ".m.safetensors.2000000000.tmp".to_string(),
            ".m.safetensors.2000000001.7.tmp".to_string(),
            // This process and a running one (init) keep theirs; other files stay.
            format!(".m.safetensors.{own}.3.tmp"),
            ".m.safetensors.1.0.tmp".to_string(),
            ".m.safetensors.x.tmp".to_string(),
            "m.safetensors".to_string(),
        ] {
            std::fs::write(d.join(name), "").unwrap();
        }
        remove_stale_temp_files(&path);
        let mut expected = vec![
            ".m.safetensors.1.0.tmp".to_string(),
            format!(".m.safetensors.{own}.3.tmp"),
            ".m.safetensors.x.tmp".to_string(),
            "m.safetensors".to_string(),
        ];
        expected.sort();
        assert_eq!(names(d), expected);
    }

    #[test]
    fn removing_through_a_link_keeps_the_link() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("real.log"), "x").unwrap();
        std::os::unix::fs::symlink("real.log", d.join("run.log")).unwrap();
        remove_output(&d.join("run.log")).unwrap();
        remove_output(&d.join("missing")).unwrap();
        assert_eq!(names(d), ["run.log"]);
        let mut f = open_append(&d.join("run.log")).unwrap();
        f.write_all(b"line\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(d.join("real.log")).unwrap(),
            "line\n"
        );
    }
}
