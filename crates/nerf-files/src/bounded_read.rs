//! Reading an input file whole, with a size limit and only when it is a regular file: a FIFO,
//! a device or a directory given where a file is expected is refused before it is opened (a
//! FIFO would block the open until a writer appears, a device could be endless), and a file
//! larger than the reader's limit is refused before it is read.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use anyhow::{anyhow, bail, Result};

/// What kind of file `meta` is, in a user's words, when it is not a regular file.
pub fn kind(meta: &std::fs::Metadata) -> &'static str {
    file_kind(meta.file_type())
}

/// What kind of file `t` is, in a user's words, when it is not a regular file: the one
/// wording of every reader's and writer's refusal.
pub(crate) fn file_kind(t: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_char_device() {
        "a character device"
    } else {
        "not a regular file"
    }
}

/// An error when `path` (symbolic links followed) is not a regular file or is larger than
/// `max_bytes`; returns its size. The error is one line naming `what` and the path.
pub fn check_regular_file(path: &Path, what: &str, max_bytes: u64) -> Result<u64> {
    let meta = std::fs::metadata(path)
        .map_err(|e| anyhow!("cannot read {what} {}: {e}", path.display()))?;
    if !meta.is_file() {
        bail!(
            "{what} {} is {}, not a regular file",
            path.display(),
            kind(&meta)
        );
    }
    if meta.len() > max_bytes {
        bail!(
            "{what} {} is {} bytes, more than the {max_bytes} this reader accepts",
            path.display(),
            meta.len()
        );
    }
    Ok(meta.len())
}

/// The bytes of the regular file `path`, at most `max_bytes` of them (checked before opening,
/// and again while reading, should the file grow meanwhile). Errors are one line naming
/// `what` (e.g. "dataset file") and the path.
pub fn read_regular_file(path: &Path, what: &str, max_bytes: u64) -> Result<Vec<u8>> {
    let len = check_regular_file(path, what, max_bytes)?;
    let file =
        File::open(path).map_err(|e| anyhow!("cannot read {what} {}: {e}", path.display()))?;
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| anyhow!("cannot read {what} {}: {e}", path.display()))?;
    if bytes.len() as u64 > max_bytes {
        bail!(
            "{what} {} grew past the {max_bytes} bytes this reader accepts while being read",
            path.display()
        );
    }
    Ok(bytes)
}

/// Makes a FIFO (named pipe) at `path`, for the tests of readers and writers that must not
/// block on one.
#[cfg(test)]
pub(crate) fn make_fifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn fifos_directories_and_large_files_are_refused_at_once() {
        let (dir, fifo) = crate::test_files::temp_file("pipe");
        make_fifo(&fifo);
        let start = Instant::now();
        let err = read_regular_file(&fifo, "dataset file", 1 << 20).unwrap_err();
        assert!(start.elapsed() < Duration::from_secs(1));
        let err = err.to_string();
        assert!(
            err.contains("FIFO") && err.contains("dataset file"),
            "{err}"
        );
        let err = read_regular_file(dir.path(), "image", 10).unwrap_err();
        assert!(err.to_string().contains("a directory"), "{err}");
        let big = dir.path().join("big");
        std::fs::write(&big, vec![7u8; 100]).unwrap();
        let err = read_regular_file(&big, "image", 99)
            .unwrap_err()
            .to_string();
        assert!(err.contains("100 bytes") && err.contains("99"), "{err}");
        assert_eq!(
            read_regular_file(&big, "image", 100).unwrap(),
            vec![7u8; 100]
        );
        let err = read_regular_file(&dir.path().join("none"), "image", 100).unwrap_err();
        assert!(err.to_string().starts_with("cannot read image"), "{err}");
    }
}
