//! `nerf import-torch`: a PyTorch state dict of the homework's NeRF (`torch.save(model.state_dict())`,
//! or a training checkpoint holding it under `model`, `model_state_dict` or `state_dict`) into
//! our safetensors checkpoint.
//!
//! Names are the pytorch3d-style module's (`mlp_xyz.mlp.{i}.0.weight`, `density_layer.0`,
//! `intermediate_linear`, `color_layer.{0,2}`, see `nerf::field::nerf`); a common prefix
//! such as `implicit_fn.` (the homework's wrapper module) is accepted. Every parameter the
//! config needs must be present with the config's shape; the error names the tensor and both
//! shapes. Extra tensors (optimizer state, other modules) are ignored.

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use candle_core::Tensor;

use crate::checkpoint::{self, CheckpointInfo};
use crate::checkpoint_error::{format_unless_typed, CheckpointError};
use crate::parameter_shapes::ParameterShapes;
use crate::pickle::Value;
use crate::torch_archive::{tensor_ref, TorchArchive};

/// Keys under which training scripts commonly nest the state dict (`model` is the
/// homework's).
const NESTED_KEYS: &[&str] = &["model", "model_state_dict", "state_dict"];

/// What a PyTorch file holds for the NeRF: the homework's training checkpoint
/// `{"model": state_dict, "optimizer": Adam's state_dict, "epoch": E}`, or a bare state dict
/// (then without optimizer state, at epoch 0).
pub struct TorchCheckpoint {
    /// The NeRF's parameters by our names, each of the config's shape.
    pub model: Vec<(String, Tensor)>,
    /// Adam's moments by our names, `adam.exp_avg.<name>` and `adam.exp_avg_sq.<name>`
    /// (empty when the file has no optimizer state).
    pub adam: Vec<(String, Tensor)>,
    /// `epoch` (the homework's: the epoch a resumed run starts at) and Adam's step count.
    pub info: CheckpointInfo,
}

/// The state dict's entries, in order: the root when it holds the model's tensors, else the
/// dict nested under one of [`NESTED_KEYS`].
fn state_dict(root: &Value, expected: &[(String, Vec<usize>)]) -> Option<Vec<(Value, Value)>> {
    let holds_model = |obj: &Value| match obj.dict() {
        Some(entries) => {
            let names: Vec<&str> = entries.iter().filter_map(|(k, _)| k.as_str()).collect();
            expected.iter().any(|(n, _)| lookup(&names, n).is_some())
        }
        None => false,
    };
    let dict = if holds_model(root) {
        root.clone()
    } else {
        NESTED_KEYS
            .iter()
            .filter_map(|k| root.get(k))
            .find(|d| holds_model(d))?
    };
    dict.dict()
}

/// Reads the NeRF (and, when present, Adam's state and the epoch) from a PyTorch file, by our
/// names, as f32 on the CPU. Every parameter must be present with the config's shape
/// (`expected`, in the module's order); an error names a missing, misshapen or non-finite tensor
/// ([`CheckpointError::MissingParameter`], [`CheckpointError::Shape`],
/// [`CheckpointError::NonFinite`]), a missing file ([`CheckpointError::NotFound`]), or what is
/// wrong with a file that does not read ([`CheckpointError::Format`]).
pub fn read_torch_checkpoint(
    path: &Path,
    expected: &ParameterShapes,
) -> Result<TorchCheckpoint, CheckpointError> {
    read_checkpoint(path, expected).map_err(|e| format_unless_typed(path, e))
}

/// [`read_torch_checkpoint`], its typed errors inside an `anyhow::Error`.
fn read_checkpoint(path: &Path, expected: &ParameterShapes) -> Result<TorchCheckpoint> {
    if !path.exists() {
        let message = format!("PyTorch file {} not found", path.display());
        return Err(CheckpointError::not_found(path, message).into());
    }
    let mut archive = TorchArchive::open(path)?;
    archive.verify()?;
    let root = archive.root.clone();
    let entries = state_dict(&root, expected).ok_or_else(|| {
        anyhow!(
            "{} holds no state dict of the homework's NeuralRadianceField (no tensor {}); if it \
             was saved with torch.save(model), a whole module, save model.state_dict() instead",
            path.display(),
            expected[0].0
        )
    })?;
    // The tensors in the state dict's order (Adam's state refers to parameters by their
    // position), which their storage keys give; only the ones the config needs are read.
    let mut found = Vec::new();
    for (k, v) in entries {
        if let Some(name) = k.as_str() {
            if let Some(t) = tensor_ref(&v).map_err(|e| anyhow!("{}: {e}", path.display()))? {
                found.push((t.key.parse::<usize>().ok(), name.to_string(), t.shape, v));
            }
        }
    }
    found.sort_by_key(|(key, _, _, _)| *key);
    let name_refs: Vec<&str> = found.iter().map(|(_, n, _, _)| n.as_str()).collect();
    let mut model = Vec::with_capacity(expected.len());
    let mut positions = Vec::with_capacity(expected.len());
    for (name, shape) in expected {
        let i = lookup(&name_refs, name).ok_or_else(|| CheckpointError::MissingParameter {
            path: path.to_path_buf(),
            name: name.clone(),
            message: format!(
                "{} has no tensor {name} (a state dict of the homework's NeuralRadianceField is expected)",
                path.display()
            ),
        })?;
        let (_, _, dims, value) = &found[i];
        if dims != shape {
            return Err(CheckpointError::Shape {
                path: path.to_path_buf(),
                name: name.clone(),
                expected: shape.clone(),
                found: dims.clone(),
                message: format!(
                    "{}: tensor {name} has shape {:?} but the config needs {:?}",
                    path.display(),
                    dims,
                    shape
                ),
            }
            .into());
        }
        let t = archive.tensor(value)?.expect("a tensor reference");
        checkpoint::ensure_finite_values(path, name, &t.flatten_all()?.to_vec1::<f32>()?)?;
        model.push((name.clone(), t));
        positions.push(i);
    }
    let (adam, adam_step) = match root.get("optimizer") {
        Some(opt) => read_adam(&mut archive, &opt, &model, &positions)?,
        None => (Vec::new(), 0),
    };
    let epoch = root
        .get("epoch")
        .and_then(|e| e.as_int())
        .unwrap_or(0)
        .max(0) as usize;
    Ok(TorchCheckpoint {
        model,
        adam,
        info: CheckpointInfo {
            epoch,
            adam_step,
            wall_seconds: 0.0,
            ..CheckpointInfo::default()
        },
    })
}

/// Adam's moments from `torch.optim.Adam.state_dict()` (`{"state": {id: {"step",
/// "exp_avg", "exp_avg_sq"}}, "param_groups": [{"params": [id, ...]}]}`): the i-th id of the
/// groups is the model's i-th parameter, the i-th tensor of its state dict. `positions`
/// gives each of `model`'s parameters' place there. Returns the moments by our names and the
/// step count (empty and 0 when Adam has not stepped).
fn read_adam(
    archive: &mut TorchArchive,
    opt: &Value,
    model: &[(String, Tensor)],
    positions: &[usize],
) -> Result<(Vec<(String, Tensor)>, u64)> {
    let path = archive.path().to_path_buf();
    let bad = |what: &str| anyhow!("{}: optimizer state {what}", path.display());
    let groups = opt
        .get("param_groups")
        .ok_or_else(|| bad("has no param_groups"))?;
    let groups = groups.list().ok_or_else(|| bad("has no param_groups"))?;
    let ids: Vec<i64> = groups
        .iter()
        .filter_map(|g| g.get("params"))
        .filter_map(|ids| {
            ids.list()
                .map(|l| l.iter().filter_map(Value::as_int).collect::<Vec<_>>())
        })
        .flatten()
        .collect();
    let state = opt
        .get("state")
        .and_then(|s| s.dict())
        .ok_or_else(|| bad("has no state"))?;
    if state.is_empty() {
        return Ok((Vec::new(), 0));
    }
    let mut moments = Vec::new();
    let mut step = 0u64;
    for ((name, param), &pos) in model.iter().zip(positions) {
        let id = *ids
            .get(pos)
            .ok_or_else(|| bad(&format!("lists no parameter for {name}")))?;
        let entry = state
            .iter()
            .find(|(k, _)| k.as_int() == Some(id))
            .map(|(_, v)| v)
            .ok_or_else(|| bad(&format!("has no entry for {name} (parameter {id})")))?;
        for key in ["exp_avg", "exp_avg_sq"] {
            let obj = entry
                .get(key)
                .ok_or_else(|| bad(&format!("lacks {key} of {name}")))?;
            let shape = tensor_ref(&obj)
                .map_err(|e| anyhow!("{}: {e}", path.display()))?
                .ok_or_else(|| bad(&format!("{key} of {name} is not a tensor")))?
                .shape;
            if shape != param.dims() {
                return Err(bad(&format!(
                    "{key} of {name} has shape {:?}, the parameter {:?} (the optimizer's parameter order does not match the state dict's)",
                    shape,
                    param.dims()
                )));
            }
            let t = archive.tensor(&obj)?.expect("a tensor reference");
            moments.push((format!("adam.{key}.{name}"), t));
        }
        if let Some(s) = entry.get("step") {
            step = match archive.tensor(&s)? {
                Some(t) => {
                    let v = t.flatten_all()?.to_vec1::<f32>()?;
                    let v = *v
                        .first()
                        .ok_or_else(|| bad(&format!("step of {name} is empty")))?;
                    if !(v.is_finite() && v >= 0.0) {
                        return Err(bad(&format!("step of {name} is {v}")));
                    }
                    v as u64
                }
                None => s.as_f64().unwrap_or(0.0).max(0.0) as u64,
            };
        }
    }
    Ok((moments, step))
}

/// Reads the NeRF parameters from a PyTorch `.pth` file, by our names, as f32 on the CPU, each
/// of the shape `expected` gives (checked); an error names a missing,
/// misshapen or non-finite tensor.
pub(crate) fn read_torch_state_dict(
    path: &Path,
    expected: &ParameterShapes,
) -> Result<Vec<(String, Tensor)>> {
    Ok(read_torch_checkpoint(path, expected)?.model)
}

/// The index of the name `name`, or of the only one ending in `.name` (a prefix such as the
/// homework's `implicit_fn.`).
fn lookup(names: &[&str], name: &str) -> Option<usize> {
    if let Some(i) = names.iter().position(|n| *n == name) {
        return Some(i);
    }
    let suffix = format!(".{name}");
    let mut matches = names
        .iter()
        .enumerate()
        .filter(|(_, k)| k.ends_with(&suffix));
    match (matches.next(), matches.next()) {
        (Some((i, _)), None) => Some(i),
        _ => None,
    }
}

/// Converts `pth` into a checkpoint at `out` (weights only; epoch 0, so training started from
/// it begins a fresh optimiser). Returns the number of parameters written.
pub fn import_torch(pth: &Path, expected: &ParameterShapes, out: &Path) -> Result<usize> {
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
    let tensors = read_torch_state_dict(pth, expected)?;
    let n = tensors.iter().map(|(_, t)| t.elem_count()).sum();
    checkpoint::save(out, &tensors, CheckpointInfo::default())?;
    Ok(n)
}

/// The prefix of the homework's parameter names: its `Model` holds the field as
/// `implicit_fn`.
pub(crate) const HOMEWORK_PREFIX: &str = "implicit_fn.";

/// What [`write_torch_checkpoint`] writes besides the weights.
#[derive(Debug, Clone, Copy)]
pub struct TorchOptimizerInfo {
    /// Adam's current learning rate (`param_groups[0]["lr"]`).
    pub lr: f64,
    /// The schedule's initial learning rate (`initial_lr`, which PyTorch's `LambdaLR` needs
    /// to resume).
    pub initial_lr: f64,
}

/// Writes the homework's training checkpoint, `torch.save({"model": state_dict, "optimizer":
/// Adam's state_dict, "epoch": E}, path)`: parameters named `implicit_fn.<name>` in the
/// module's order (`expected`), Adam's moments `adam.exp_avg.<name>` /
/// `adam.exp_avg_sq.<name>` from `tensors` as its per-parameter state (with `step`) when
/// present, and `epoch` = epochs completed (the epoch a resumed run starts at).
pub fn write_torch_checkpoint(
    path: &Path,
    expected: &ParameterShapes,
    tensors: &std::collections::HashMap<String, Tensor>,
    info: CheckpointInfo,
    optimizer: TorchOptimizerInfo,
) -> Result<()> {
    use crate::torch_save::{torch_save, PyValue};
    let names: Vec<String> = expected.iter().map(|(n, _)| n.clone()).collect();
    let mut model = Vec::with_capacity(names.len());
    let mut state = Vec::new();
    for (i, name) in names.iter().enumerate() {
        let t = tensors
            .get(name)
            .ok_or_else(|| anyhow!("no parameter {name} to save"))?;
        model.push((
            format!("{HOMEWORK_PREFIX}{name}"),
            PyValue::Tensor(t.clone()),
        ));
        let moments = (
            tensors.get(&format!("adam.exp_avg.{name}")),
            tensors.get(&format!("adam.exp_avg_sq.{name}")),
        );
        if let (Some(m), Some(v)) = moments {
            if info.adam_step > 0 {
                let step = Tensor::new(info.adam_step as f32, m.device())?;
                state.push((
                    PyValue::Int(i as i64),
                    PyValue::Dict(vec![
                        (PyValue::Str("step".into()), PyValue::Tensor(step)),
                        (PyValue::Str("exp_avg".into()), PyValue::Tensor(m.clone())),
                        (
                            PyValue::Str("exp_avg_sq".into()),
                            PyValue::Tensor(v.clone()),
                        ),
                    ]),
                ));
            }
        }
    }
    let s = |k: &str| PyValue::Str(k.to_string());
    let group = adam_param_group(optimizer, names.len());
    let root = PyValue::Dict(vec![
        (s("model"), PyValue::OrderedDict(model)),
        (
            s("optimizer"),
            PyValue::Dict(vec![
                (s("state"), PyValue::Dict(state)),
                (s("param_groups"), PyValue::List(vec![group])),
            ]),
        ),
        (s("epoch"), PyValue::Int(info.epoch as i64)),
    ]);
    torch_save(path, &root)
}

/// `torch.optim.Adam`'s one parameter group (PyTorch's defaults, no weight decay) over `n`
/// parameters, with the current and the schedule's initial learning rate.
fn adam_param_group(optimizer: TorchOptimizerInfo, n: usize) -> crate::torch_save::PyValue {
    use crate::torch_save::PyValue;
    let s = |k: &str| PyValue::Str(k.to_string());
    PyValue::Dict(vec![
        (s("lr"), PyValue::Float(optimizer.lr)),
        (
            s("betas"),
            PyValue::Tuple(vec![PyValue::Float(0.9), PyValue::Float(0.999)]),
        ),
        (s("eps"), PyValue::Float(1e-8)),
        (s("weight_decay"), PyValue::Int(0)),
        (s("amsgrad"), PyValue::Bool(false)),
        (s("maximize"), PyValue::Bool(false)),
        (s("foreach"), PyValue::None),
        (s("capturable"), PyValue::Bool(false)),
        (s("differentiable"), PyValue::Bool(false)),
        (s("fused"), PyValue::None),
        (s("initial_lr"), PyValue::Float(optimizer.initial_lr)),
        (
            s("params"),
            PyValue::List((0..n as i64).map(PyValue::Int).collect()),
        ),
    ])
}
