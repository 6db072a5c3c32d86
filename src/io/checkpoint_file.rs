//! A NeRF checkpoint file of either format, told apart by its content (never its name):
//! ours (safetensors: an 8-byte header length, then a JSON header starting with `{`) or
//! PyTorch's (`torch.save`: a zip archive), and where a checkpoint path points.
//!
//! The rule for a path (`--checkpoint`, or the config's `training.checkpoint_path`):
//! * a file is the checkpoint, in either format (the homework's `checkpoint_path` is such a
//!   file: `torch.save({"model", "optimizer", "epoch"}, checkpoint_path)`);
//! * a directory holds it: `<dir>/<stem>.safetensors` (`nerf_<dataset_name>`, where
//!   `nerf train` writes), or else its only checkpoint file of either format;
//! * a path that does not exist is, for training, a directory to create (a new run writes
//!   `<dir>/<stem>.safetensors`), and for rendering an error.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use candle_core::{Device, Tensor};

use crate::field::nerf::NerfParams;
use crate::io::checkpoint::{self, CheckpointInfo};
use crate::io::torch::read_torch_checkpoint;
use crate::io::torch_archive::looks_like_torch;

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
/// `torch.save` file is a zip archive (or a legacy pickle stream). An error names a file that
/// is neither.
pub fn detect_format(path: &Path) -> Result<CheckpointFormat> {
    let mut head = [0u8; 9];
    let mut file = std::fs::File::open(path)
        .with_context(|| format!("cannot read checkpoint {}", path.display()))?;
    let len = file.metadata()?.len();
    let n = file.read(&mut head)?;
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
    bail!(
        "checkpoint {} is corrupt or not a checkpoint (neither safetensors nor a PyTorch file)",
        path.display()
    )
}

/// Every tensor of a checkpoint of either format, by our names (the model's parameters and,
/// when saved, `adam.exp_avg.*` / `adam.exp_avg_sq.*`; a safetensors checkpoint may also hold
/// an occupancy grid), on `device`, and what it says about training progress. A PyTorch file
/// is read for the NeRF of `config` (names and shapes checked).
pub fn load(
    path: &Path,
    config: &NerfParams,
    device: &Device,
) -> Result<(HashMap<String, Tensor>, CheckpointInfo)> {
    match detect_format(path)? {
        CheckpointFormat::Safetensors => checkpoint::load(path, device),
        CheckpointFormat::Torch => {
            let torch = read_torch_checkpoint(path, config)?;
            let tensors = torch
                .model
                .into_iter()
                .chain(torch.adam)
                .map(|(n, t)| Ok((n, t.to_device(device)?)))
                .collect::<Result<_>>()?;
            Ok((tensors, torch.info))
        }
    }
}

/// The checkpoint file `path` names for reading (see the module's rule); an error says what
/// is missing or ambiguous.
pub fn resolve(path: &Path, stem: &str) -> Result<PathBuf> {
    if path.is_file() {
        return Ok(path.to_path_buf());
    }
    if !path.is_dir() {
        bail!("checkpoint {} not found", path.display());
    }
    let ours = path.join(format!("{stem}.safetensors"));
    if ours.is_file() {
        return Ok(ours);
    }
    let mut found: Vec<PathBuf> = std::fs::read_dir(path)
        .with_context(|| format!("cannot read checkpoint directory {}", path.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && detect_format(p).is_ok())
        .collect();
    found.sort();
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => bail!(
            "checkpoint directory {} holds no checkpoint (expected {})",
            path.display(),
            ours.display()
        ),
        _ => bail!(
            "checkpoint directory {} holds several checkpoints ({}); name one with --checkpoint",
            path.display(),
            found
                .iter()
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().to_string()))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// The checkpoint file training reads and writes for `training.checkpoint_path`: the path
/// itself when it is a file, else `<path>/<stem>.safetensors`.
pub fn training_checkpoint(path: &Path, stem: &str) -> PathBuf {
    if path.is_file() {
        path.to_path_buf()
    } else {
        path.join(format!("{stem}.safetensors"))
    }
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
        assert!(resolve(d, "nerf_lego")
            .unwrap_err()
            .to_string()
            .contains("holds no checkpoint"));
        std::fs::write(d.join("a.pth"), b"PK\x03\x04").unwrap();
        std::fs::write(d.join("notes.txt"), b"not a checkpoint").unwrap();
        assert_eq!(resolve(d, "nerf_lego").unwrap(), d.join("a.pth"));
        std::fs::write(d.join("b.ckpt"), b"PK\x03\x04").unwrap();
        let err = resolve(d, "nerf_lego").unwrap_err().to_string();
        assert!(err.contains("a.pth, b.ckpt"), "{err}");
        // Ours by name wins.
        let ours = d.join("nerf_lego.safetensors");
        std::fs::write(&ours, b"").unwrap();
        assert_eq!(resolve(d, "nerf_lego").unwrap(), ours);
        assert_eq!(training_checkpoint(d, "nerf_lego"), ours);
        assert_eq!(training_checkpoint(&d.join("a.pth"), "x"), d.join("a.pth"));
        assert!(resolve(&d.join("none"), "x").is_err());
    }
}
