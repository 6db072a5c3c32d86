//! `nerf import-torch`: a PyTorch state dict of the homework's NeRF (`torch.save(model.state_dict())`,
//! or a training checkpoint holding it under `model`, `model_state_dict` or `state_dict`) into
//! our safetensors checkpoint.
//!
//! Names are the pytorch3d-style module's (`mlp_xyz.mlp.{i}.0.weight`, `density_layer.0`,
//! `intermediate_linear`, `color_layer.{0,2}`, see [`crate::field::nerf`]); a common prefix
//! such as `implicit_fn.` (the homework's wrapper module) is accepted. Every parameter the
//! config needs must be present with the config's shape; the error names the tensor and both
//! shapes. Extra tensors (optimizer state, other modules) are ignored.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{anyhow, bail, Result};
use candle_core::{DType, Device, Tensor};

use crate::field::nerf::parameter_shapes;
use crate::field::nerf::NerfParams;
use crate::io::checkpoint::{self, CheckpointInfo};

/// Keys under which training scripts commonly nest the state dict.
const NESTED_KEYS: &[&str] = &["model", "model_state_dict", "state_dict"];

/// Reads the NeRF parameters from a PyTorch `.pth` file, by our names, as f32 on the CPU, each
/// of the shape [`parameter_shapes`] gives for `config` (checked); an error names a missing,
/// misshapen or non-finite tensor.
pub fn read_torch_state_dict(path: &Path, config: &NerfParams) -> Result<Vec<(String, Tensor)>> {
    if !path.is_file() {
        bail!("PyTorch file {} not found", path.display());
    }
    verify_archive(path)?;
    let expected = parameter_shapes(config);
    let read = |key: Option<&str>| -> Result<HashMap<String, Tensor>> {
        let tensors = candle_core::pickle::read_all_with_key(path, key).map_err(|e| {
            anyhow!(
                "cannot read {} as a PyTorch state dict: {e}",
                path.display()
            )
        })?;
        Ok(tensors.into_iter().collect())
    };
    let mut found = read(None)?;
    if !expected.iter().any(|(n, _)| lookup(&found, n).is_some()) {
        for key in NESTED_KEYS {
            if let Ok(nested) = read(Some(key)) {
                if expected.iter().any(|(n, _)| lookup(&nested, n).is_some()) {
                    found = nested;
                    break;
                }
            }
        }
    }
    if found.is_empty() {
        bail!(
            "{} holds no tensors by name: if it was saved with torch.save(model), a whole \
             module, save model.state_dict() instead",
            path.display()
        );
    }
    let mut out = Vec::with_capacity(expected.len());
    for (name, shape) in expected {
        let t = lookup(&found, &name).ok_or_else(|| {
            anyhow!(
                "{} has no tensor {name} (a state dict of the homework's NeuralRadianceField is expected)",
                path.display()
            )
        })?;
        if t.dims() != &shape[..] {
            bail!(
                "{}: tensor {name} has shape {:?} but the config needs {:?}",
                path.display(),
                t.dims(),
                shape
            );
        }
        let t = t
            .to_dtype(DType::F32)?
            .to_device(&Device::Cpu)?
            .contiguous()?;
        checkpoint::ensure_finite_values(path, &name, &t.flatten_all()?.to_vec1::<f32>()?)?;
        out.push((name, t));
    }
    Ok(out)
}

/// Reads every member of the `.pth` zip archive through to its end, so that one whose stored
/// CRC-32 does not match its bytes is an error naming it (PyTorch loads such files without a
/// word).
pub fn verify_archive(path: &Path) -> Result<()> {
    let file =
        std::fs::File::open(path).map_err(|e| anyhow!("cannot read {}: {e}", path.display()))?;
    let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file)).map_err(|e| {
        anyhow!(
            "{} is not a PyTorch file (zip archive): {e}",
            path.display()
        )
    })?;
    for i in 0..archive.len() {
        let mut member = archive
            .by_index(i)
            .map_err(|e| anyhow!("{}: member {i}: {e}", path.display()))?;
        let name = member
            .name()
            .map_or_else(|_| format!("#{i}"), |n| n.to_string());
        std::io::copy(&mut member, &mut std::io::sink()).map_err(|e| {
            anyhow!(
                "{}: member {name} is corrupt ({e}); the file is damaged",
                path.display()
            )
        })?;
    }
    Ok(())
}

/// The tensor named `name`, or the only one named `<prefix>.name`.
fn lookup<'a>(tensors: &'a HashMap<String, Tensor>, name: &str) -> Option<&'a Tensor> {
    if let Some(t) = tensors.get(name) {
        return Some(t);
    }
    let suffix = format!(".{name}");
    let mut matches = tensors.iter().filter(|(k, _)| k.ends_with(&suffix));
    match (matches.next(), matches.next()) {
        (Some((_, t)), None) => Some(t),
        _ => None,
    }
}

/// Converts `pth` into a checkpoint at `out` (weights only; epoch 0, so training started from
/// it begins a fresh optimiser). Returns the number of parameters written.
pub fn import_torch(pth: &Path, config: &NerfParams, out: &Path) -> Result<usize> {
    if out
        .canonicalize()
        .ok()
        .is_some_and(|o| pth.canonicalize().ok() == Some(o))
    {
        bail!(
            "--out {} is the PyTorch file itself; choose another path",
            out.display()
        );
    }
    let tensors = read_torch_state_dict(pth, config)?;
    let n = tensors.iter().map(|(_, t)| t.elem_count()).sum();
    checkpoint::save(out, &tensors, CheckpointInfo::default())?;
    Ok(n)
}
