//! `nerf export model`: a training checkpoint reduced to what rendering needs — the model's
//! parameters and its occupancy grid, without the optimiser's state (two moments per
//! parameter, and a step count per hash-table row), with an NGP's hash table stored as f16.
//! This is how the shipped hash-grid checkpoints are made: a 2^18-row, 16-level table with its
//! Adam state is about 135 MB; the table alone in f16 is 17 MB.

use std::path::Path;

use anyhow::{bail, Result};
use candle_core::{DType, Device, Tensor};

use nerf::config::Config;
use nerf::io::checkpoint;

/// What [`export_model`] wrote.
#[derive(Debug, Clone, Copy)]
pub struct ModelExport {
    /// Tensors written.
    pub tensors: usize,
    /// Size of the file in bytes.
    pub bytes: u64,
    /// Largest absolute change of a table value by the f16 rounding (0 without a table).
    pub table_rounding: f32,
}

/// Writes the model of the checkpoint [`Config::checkpoint`] picks for `checkpoint` to `out`
/// (temp file + rename): every tensor but the optimiser's (`adam.*`), an NGP's table as f16.
/// The written file is loaded back as the config's field before this returns.
pub fn export_model(
    config: &Config,
    checkpoint: Option<&Path>,
    out: &Path,
    device: &Device,
) -> Result<ModelExport> {
    if config.implicit_function.is_sdf_volume() {
        bail!("implicit_function.type sdf_volume: an SDF scene has no checkpoint to export");
    }
    let source = config.checkpoint(checkpoint);
    config.ensure_checkpoint(&source)?;
    // The same file by any name (a link, `dir/../dir/x`): writing it would replace the
    // training checkpoint with the model alone.
    let same = source == out
        || matches!(
            (std::fs::canonicalize(&source), std::fs::canonicalize(out)),
            (Ok(a), Ok(b)) if a == b
        );
    if same {
        bail!(
            "--out {} is the checkpoint itself; write the model elsewhere",
            out.display()
        );
    }
    let (tensors, info) = checkpoint::load(&source, device)?;
    let mut kept: Vec<(String, Tensor)> = tensors
        .into_iter()
        .filter(|(name, _)| !name.starts_with("adam."))
        .collect();
    kept.sort_by(|a, b| a.0.cmp(&b.0));
    // The sparsely updated tables (the hash grid's) are most of the model: kept in half
    // precision.
    let tables: Vec<String> = config
        .field_spec()?
        .seeded(0, device)?
        .param_groups()
        .sparse_rows
        .into_iter()
        .map(|g| g.name)
        .collect();
    let mut table_rounding = 0f32;
    for (name, t) in kept.iter_mut() {
        if tables.contains(name) {
            let half = t.to_dtype(DType::F16)?;
            table_rounding = (half.to_dtype(DType::F32)? - &*t)?
                .abs()?
                .flatten_all()?
                .max(0)?
                .to_scalar::<f32>()?;
            *t = half;
        }
    }
    checkpoint::save(out, &kept, info)?;
    // A regular file (through any links) loads as the config's field (names, shapes, values
    // checked), or it is removed; what was written to a device or FIFO (`/dev/null`, a pipe)
    // cannot be read back, and the node itself is never removed.
    let written = std::fs::canonicalize(out).unwrap_or_else(|_| out.to_path_buf());
    let regular = std::fs::metadata(&written).is_ok_and(|m| m.is_file());
    if regular {
        if let Err(e) = config.load_field(&written, device) {
            let _ = std::fs::remove_file(&written);
            return Err(e.context(format!("the exported {} does not load", out.display())));
        }
    }
    Ok(ModelExport {
        tensors: kept.len(),
        bytes: if regular {
            std::fs::metadata(&written)?.len()
        } else {
            0
        },
        table_rounding,
    })
}
