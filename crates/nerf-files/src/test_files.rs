//! What the file readers' and writers' unit tests share: a fresh temporary directory with a
//! path in it.

use std::path::PathBuf;

/// A new temporary directory (removed when the returned guard drops) and the path `name`
/// inside it (not created).
pub fn temp_file(name: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let path = dir.path().join(name);
    (dir, path)
}
