//! The one writing rule through the binary: `nerf export mesh --out` onto a symbolic link
//! writes the file it points to and keeps the link; onto `/dev/null` writes the device and
//! keeps it one; onto a directory is refused in one line. `nerf export model` onto a device
//! keeps the device, and onto its own checkpoint by another name is refused.

use std::os::unix::fs::FileTypeExt;
use std::path::Path;

mod common;
use common::{export_args, nerf, sorted_names, stderr};

/// `nerf export mesh` of the analytic sphere (fast) to `out`.
fn export_mesh(out: &Path) -> std::process::Output {
    nerf(&export_args(
        "mesh",
        "sphere",
        &["--resolution", "16"],
        out.to_str().unwrap(),
    ))
}

#[test]
fn export_onto_a_link_writes_its_target_and_keeps_the_link() {
    let (dir, real) = common::scratch("meshes");
    std::fs::create_dir(&real).unwrap();
    std::fs::write(real.join("sphere.ply"), "old").unwrap();
    let link = dir.path().join("latest.ply");
    std::os::unix::fs::symlink("meshes/sphere.ply", &link).unwrap();
    let o = export_mesh(&link);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    let bytes = std::fs::read(real.join("sphere.ply")).unwrap();
    assert!(
        bytes.starts_with(b"ply\n"),
        "the link's target was not written"
    );
    assert!(bytes.windows(13).any(|w| w == b"element face "));
    // No temporary file beside the link or the target.
    assert_eq!(sorted_names(&real), ["sphere.ply"]);
    assert_eq!(sorted_names(dir.path()), ["latest.ply", "meshes"]);
}

#[test]
fn export_onto_dev_null_writes_the_device() {
    let null = Path::new("/dev/null");
    let o = export_mesh(null);
    let still_a_device = std::fs::symlink_metadata(null)
        .map(|m| m.file_type().is_char_device())
        .unwrap_or(false);
    if !still_a_device {
        // Put the machine's /dev/null back (character device 1, 3) before failing.
        let _ = std::fs::remove_file(null);
        let c = std::ffi::CString::new("/dev/null").unwrap();
        unsafe { libc::mknod(c.as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) };
        panic!("nerf export replaced /dev/null");
    }
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn export_onto_a_directory_is_refused_in_one_line() {
    let (dir, target) = common::scratch("out.ply");
    std::fs::create_dir(&target).unwrap();
    let o = export_mesh(&target);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("is a directory"), "{err}");
    assert!(sorted_names(&target).is_empty());
    assert_eq!(sorted_names(dir.path()), ["out.ply"]);
}

/// `nerf export model` of the shipped NeRF (from `checkpoint`) to `out`.
fn export_model(checkpoint: &Path, out: &Path) -> std::process::Output {
    nerf(&export_args(
        "model",
        "nerf_lego",
        &["--checkpoint", checkpoint.to_str().unwrap()],
        out.to_str().unwrap(),
    ))
}

#[test]
fn export_model_onto_a_device_keeps_the_device() {
    let (_dir, node) = common::scratch("null");
    let c = std::ffi::CString::new(node.to_str().unwrap()).unwrap();
    let made = unsafe { libc::mknod(c.as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) };
    if made != 0 {
        eprintln!("SKIPPED export_model_onto_a_device_keeps_the_device: mknod needs root");
        return;
    }
    let shipped = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("checkpoints/nerf_lego.safetensors");
    let o = export_model(&shipped, &node);
    assert!(o.status.success(), "{}", stderr(&o));
    let kept = std::fs::symlink_metadata(&node).map(|m| m.file_type().is_char_device());
    assert!(
        matches!(kept, Ok(true)),
        "the device node was removed or replaced"
    );
}

#[test]
fn export_model_onto_its_own_checkpoint_by_another_name_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .join("checkpoints/nerf_lego.safetensors");
    let checkpoint = dir.path().join("mlp.safetensors");
    std::fs::copy(&shipped, &checkpoint).unwrap();
    let before = std::fs::read(&checkpoint).unwrap();
    let alias = dir.path().join("alias.safetensors");
    std::os::unix::fs::symlink("mlp.safetensors", &alias).unwrap();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    for out in [alias, sub.join("../mlp.safetensors")] {
        let o = export_model(&checkpoint, &out);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains("is the checkpoint itself"), "{err}");
    }
    assert_eq!(
        std::fs::read(&checkpoint).unwrap(),
        before,
        "checkpoint untouched"
    );
}
