//! A NeRF checkpoint file of either format, told apart by its content (never its name):
//! ours (safetensors: an 8-byte header length, then a JSON header starting with `{`) or
//! PyTorch's (`torch.save`: a zip archive), and where a checkpoint path points.
//!
//! The rule for a path (`--checkpoint`, or the config's `training.checkpoint_path`):
//! * a file is the checkpoint, in either format (the homework's `checkpoint_path` is such a
//!   file: `torch.save({"model", "optimizer", "epoch"}, checkpoint_path)`);
//! * a directory holds it: `<dir>/<stem>.safetensors` (`nerf_<dataset_name>`, where
//!   `nerf train` writes), or else its only checkpoint file of either format; several are an
//!   error naming them (for every command, training included); none is an error for reading
//!   and a fresh run writing `<dir>/<stem>.safetensors` for training;
//! * a path that does not exist is, for training, the file (a name with an extension) or the
//!   directory a new run writes, and for reading an error (a relative path's says the absolute
//!   path it was tried at).
//!
//! [`resolve_for`] is the one function that applies it.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::Result;
use candle_core::{Device, Tensor};

use crate::checkpoint::{self, CheckpointInfo};
use crate::checkpoint_error::CheckpointError;
use crate::parameter_shapes::ParameterShapes;
use crate::torch::read_torch_checkpoint;
use crate::torch_archive::looks_like_torch;

/// The two checkpoint formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CheckpointFormat {
    /// Ours: safetensors with PyTorch's parameter names, `adam.*` moments and metadata.
    Safetensors,
    /// PyTorch's `torch.save` zip archive (the homework's checkpoint).
    Torch,
}

/// The format of the file at `path`, from its first bytes: a safetensors file is an 8-byte
/// little-endian header length that fits in the file, then the JSON header's `{`; a
/// `torch.save` file is a zip archive (or a legacy pickle stream). An error names a missing
/// file ([`CheckpointError::NotFound`]) or one that is neither ([`CheckpointError::Format`]).
pub fn detect_format(path: &Path) -> Result<CheckpointFormat, CheckpointError> {
    let mut head = [0u8; 9];
    let unreadable = |e| CheckpointError::unreadable(path, e);
    let mut file = std::fs::File::open(path).map_err(unreadable)?;
    let len = file.metadata().map_err(unreadable)?.len();
    let n = file.read(&mut head).map_err(unreadable)?;
    let head = &head[..n];
    if n == 9 && head[8] == b'{' {
        let header = u64::from_le_bytes(head[..8].try_into().expect("8 bytes"));
        if header <= len.saturating_sub(8) {
            return Ok(CheckpointFormat::Safetensors);
        }
    }
    if looks_like_torch(head) {
        return Ok(CheckpointFormat::Torch);
    }
    let message = format!(
        "checkpoint {} is corrupt or not a checkpoint (neither safetensors nor a PyTorch file)",
        path.display()
    );
    Err(CheckpointError::format(path, message))
}

/// Every tensor of a checkpoint of either format, by our names (the model's parameters and,
/// when saved, `adam.exp_avg.*` / `adam.exp_avg_sq.*`; a safetensors checkpoint may also hold
/// an occupancy grid), on `device`, and what it says about training progress. A PyTorch file
/// is read for the parameters `expected` (names and shapes checked). Errors: see
/// [`CheckpointError`].
pub fn load(
    path: &Path,
    expected: &ParameterShapes,
    device: &Device,
) -> Result<(HashMap<String, Tensor>, CheckpointInfo), CheckpointError> {
    match detect_format(path)? {
        CheckpointFormat::Safetensors => checkpoint::load(path, device),
        CheckpointFormat::Torch => {
            let torch = read_torch_checkpoint(path, expected)?;
            let tensors = torch
                .model
                .into_iter()
                .chain(torch.adam)
                .map(|(n, t)| Ok((n, t.to_device(device)?)))
                .collect::<Result<_>>()
                .map_err(CheckpointError::Other)?;
            torch.info.validate(path)?;
            Ok((tensors, torch.info))
        }
    }
}

/// An error unless `tensors` (a checkpoint's, read from `origin`) hold every parameter of
/// `expected` at its shape: [`CheckpointError::MissingParameter`] or
/// [`CheckpointError::Shape`] for the first that is not, in `expected`'s order, naming the
/// field `kind` the checkpoint should be of.
pub fn check_parameters(
    tensors: &HashMap<String, Tensor>,
    expected: &ParameterShapes,
    kind: &str,
    origin: &Path,
) -> Result<(), CheckpointError> {
    for (name, shape) in expected {
        let (path, name) = (origin.to_path_buf(), name.clone());
        let Some(t) = tensors.get(&name) else {
            let message = format!(
                "checkpoint {} lacks tensor {name} (is it a {kind} checkpoint of this config's sizes?)",
                origin.display()
            );
            return Err(CheckpointError::MissingParameter {
                path,
                name,
                message,
            });
        };
        if t.dims() != &shape[..] {
            let message = format!(
                "checkpoint {}: tensor {name} has shape {:?} but the config needs {:?}",
                origin.display(),
                t.dims(),
                shape
            );
            return Err(CheckpointError::Shape {
                path,
                name,
                expected: shape.clone(),
                found: t.dims().to_vec(),
                message,
            });
        }
    }
    Ok(())
}

/// What a checkpoint path is resolved for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Purpose {
    /// render, eval, view, export, report: the checkpoint must exist.
    Read,
    /// train: a checkpoint to resume from, or the file a fresh run writes.
    Train,
}

/// For an error about a missing `path`: where a relative path was looked for
/// (`; relative to the working directory: /abs/path`, to close a parenthesis), or nothing for
/// an absolute path.
pub fn relative_note(path: &Path) -> String {
    if path.is_absolute() {
        return String::new();
    }
    let relative: PathBuf = path
        .components()
        .filter(|c| *c != std::path::Component::CurDir)
        .collect();
    let tried = std::env::current_dir().unwrap_or_default().join(relative);
    format!("; relative to the working directory: {}", tried.display())
}

/// The checkpoints in directory `dir` (files of either format, by content), sorted.
pub(crate) fn checkpoints_in(dir: &Path) -> Result<Vec<PathBuf>, CheckpointError> {
    use anyhow::Context;
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read checkpoint directory {}", dir.display()))
        .map_err(CheckpointError::Other)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && detect_format(p).is_ok())
        .collect();
    found.sort();
    Ok(found)
}

/// The one rule for a checkpoint path, for every command (see the module's rule): a file is
/// the checkpoint; a directory holds `<stem>.safetensors` (where `nerf train` writes) or else
/// its only checkpoint (several: an error naming them; none: for reading an error naming the
/// directory, for training `<dir>/<stem>.safetensors`, a fresh run); a missing path is an
/// error for reading (a relative one says where it was tried) and for training the file (a
/// name with an extension) or directory a fresh run writes. Errors:
/// [`CheckpointError::NotFound`], [`CheckpointError::Ambiguous`] (several), and
/// [`CheckpointError::Format`] for a path that is neither a file nor a directory.
pub fn resolve_for(path: &Path, stem: &str, purpose: Purpose) -> Result<PathBuf, CheckpointError> {
    let ours = path.join(format!("{stem}.safetensors"));
    if path.is_file() {
        return Ok(path.to_path_buf());
    }
    if path.is_dir() {
        if ours.is_file() {
            return Ok(ours);
        }
        let mut found = checkpoints_in(path)?;
        return match (found.len(), purpose) {
            (1, _) => Ok(found.remove(0)),
            (0, Purpose::Train) => Ok(ours),
            (0, Purpose::Read) => Err(CheckpointError::not_found(
                path,
                format!(
                    "checkpoint directory {} holds no checkpoint (expected {} or one checkpoint \
                     file{})",
                    path.display(),
                    ours.display(),
                    relative_note(path)
                ),
            )),
            (_, purpose) => {
                let message = format!(
                    "checkpoint directory {} holds several checkpoints ({}); name one with {}",
                    path.display(),
                    found
                        .iter()
                        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().to_string()))
                        .collect::<Vec<_>>()
                        .join(", "),
                    match purpose {
                        Purpose::Read => "--checkpoint",
                        Purpose::Train => "training.checkpoint_path=FILE",
                    }
                );
                Err(CheckpointError::Ambiguous {
                    dir: path.to_path_buf(),
                    found,
                    message,
                })
            }
        };
    }
    if let Ok(m) = std::fs::metadata(path) {
        let message = format!(
            "checkpoint {} is {}, neither a file nor a directory",
            path.display(),
            nerf_files::bounded_read::kind(&m)
        );
        return Err(CheckpointError::format(path, message));
    }
    match purpose {
        Purpose::Read => Err(CheckpointError::not_found(
            path,
            format!(
                "checkpoint {} not found (name a checkpoint file, or a directory holding one{})",
                path.display(),
                relative_note(path)
            ),
        )),
        Purpose::Train if path.extension().is_some() => Ok(path.to_path_buf()),
        Purpose::Train => Ok(ours),
    }
}

/// The checkpoint file `path` names for reading ([`resolve_for`] with [`Purpose::Read`]).
pub fn resolve(path: &Path, stem: &str) -> Result<PathBuf, CheckpointError> {
    resolve_for(path, stem, Purpose::Read)
}

/// An error unless `path` is a file: "not found" ([`CheckpointError::NotFound`], with how to
/// make one; a relative path also as the absolute path tried), not a regular file
/// ([`CheckpointError::Format`]) or, for a directory that
/// [`crate::checkpoint_file::resolve`] could not turn into its one checkpoint, what it holds
/// ([`CheckpointError::Ambiguous`]; [`CheckpointError::NotFound`] when it holds none).
pub fn ensure_checkpoint_file(path: &Path) -> Result<(), CheckpointError> {
    if path.is_dir() {
        let found = checkpoints_in(path)?;
        let message = format!(
            "checkpoint {} is a directory holding {} checkpoint files (a directory is taken \
             when it holds exactly one; else name the file)",
            path.display(),
            found.len()
        );
        return Err(match found.len() {
            0 => CheckpointError::not_found(path, message),
            _ => CheckpointError::Ambiguous {
                dir: path.to_path_buf(),
                found,
                message,
            },
        });
    }
    if path.exists() && !path.is_file() {
        let message = format!(
            "checkpoint {} is not a regular file (a device, FIFO or socket); name a checkpoint file",
            path.display()
        );
        return Err(CheckpointError::format(path, message));
    }
    if !path.is_file() {
        let message = format!(
            "checkpoint {} not found (train one with `nerf train --config nerf_lego_fast`{})",
            path.display(),
            relative_note(path)
        );
        return Err(CheckpointError::not_found(path, message));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_is_told_by_content() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, bytes: &[u8]| {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        // A safetensors header of 0x480 bytes starts with 0x80, as a pickle stream does.
        let mut st = 0x480u64.to_le_bytes().to_vec();
        st.push(b'{');
        st.resize(8 + 0x480, b' ');
        let st = write("model.pth", &st);
        assert_eq!(detect_format(&st).unwrap(), CheckpointFormat::Safetensors);
        let zip = write("model.safetensors", b"PK\x03\x04rest of a zip");
        assert_eq!(detect_format(&zip).unwrap(), CheckpointFormat::Torch);
        let legacy = write("old", &[0x80, 0x02, 0x8a, 0x0a, 0x6c, 0xfc]);
        assert_eq!(detect_format(&legacy).unwrap(), CheckpointFormat::Torch);
        // A header length past the end of the file is not safetensors.
        let mut short = 1000u64.to_le_bytes().to_vec();
        short.push(b'{');
        let short = write("short", &short);
        assert!(detect_format(&short)
            .unwrap_err()
            .to_string()
            .contains("not a checkpoint"));
        let text = write("notes.txt", b"hello world");
        assert!(detect_format(&text).is_err());
    }

    #[test]
    fn directories_hold_one_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let train = |p: &Path| resolve_for(p, "nerf_lego", Purpose::Train);
        let err = resolve(d, "nerf_lego").unwrap_err().to_string();
        assert!(err.contains("holds no checkpoint"), "{err}");
        // Training starts fresh in an empty directory, writing ours.
        assert_eq!(train(d).unwrap(), d.join("nerf_lego.safetensors"));
        std::fs::write(d.join("a.pth"), b"PK\x03\x04").unwrap();
        std::fs::write(d.join("notes.txt"), b"not a checkpoint").unwrap();
        assert_eq!(resolve(d, "nerf_lego").unwrap(), d.join("a.pth"));
        assert_eq!(train(d).unwrap(), d.join("a.pth"));
        std::fs::write(d.join("b.ckpt"), b"PK\x03\x04").unwrap();
        for err in [resolve(d, "nerf_lego"), train(d)] {
            let err = err.unwrap_err().to_string();
            assert!(err.contains("several checkpoints (a.pth, b.ckpt)"), "{err}");
        }
        // Ours by name wins.
        let ours = d.join("nerf_lego.safetensors");
        std::fs::write(&ours, b"").unwrap();
        assert_eq!(resolve(d, "nerf_lego").unwrap(), ours);
        assert_eq!(train(d).unwrap(), ours);
        assert_eq!(train(&d.join("a.pth")).unwrap(), d.join("a.pth"));
        // Missing: an error to read, the place a fresh run writes to train.
        assert!(resolve(&d.join("none"), "x").is_err());
        assert_eq!(
            train(&d.join("new")).unwrap(),
            d.join("new/nerf_lego.safetensors")
        );
        assert_eq!(train(&d.join("m.pth")).unwrap(), d.join("m.pth"));
    }

    #[test]
    fn a_missing_relative_path_says_where_it_was_tried() {
        let err = resolve(Path::new("no/such.safetensors"), "x")
            .unwrap_err()
            .to_string();
        let cwd = std::env::current_dir().unwrap();
        let tried = cwd.join("no/such.safetensors");
        assert!(
            err.contains("relative to the working directory")
                && err.contains(&tried.display().to_string()),
            "{err}"
        );
        let err = resolve(&tried, "x").unwrap_err().to_string();
        assert!(!err.contains("relative"), "{err}");
    }
}
