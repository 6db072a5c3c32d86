//! Reading `torch.save` files: a zip archive holding `<name>/data.pkl` (the pickled object,
//! protocol 2) and `<name>/data/<key>` (each tensor storage's raw bytes). The object is
//! parsed with Candle's pickle reader into a tree of [`Object`]s (dicts keep their order, an
//! `OrderedDict` included); a tensor in it is a `torch._utils._rebuild_tensor_v2` call whose
//! storage is a persistent id naming its record in the archive.
//!
//! Legacy files (`torch.save(..., _use_new_zipfile_serialization=False)`, a bare pickle
//! stream) are refused with a message saying how to re-save them.

use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use candle_core::pickle::{Object, Stack};
use candle_core::{DType, Device, Tensor};

/// An opened `torch.save` archive: its parsed object and its records.
pub struct TorchArchive {
    path: PathBuf,
    zip: zip::ZipArchive<Cursor<Vec<u8>>>,
    /// The records' folder inside the archive (`<name>/data`).
    data_dir: PathBuf,
    /// The unpickled object.
    pub root: Object,
}

impl TorchArchive {
    /// Opens and unpickles `path`; an error names the file and what is wrong with it.
    pub fn open(path: &Path) -> Result<Self> {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        if is_legacy_torch(&bytes) {
            bail!(
                "{} is a legacy (non-zip) PyTorch file; re-save it with torch.save(obj, path) from PyTorch 1.6 or later",
                path.display()
            );
        }
        let mut zip = zip::ZipArchive::new(Cursor::new(bytes))
            .map_err(|e| anyhow!("{} is not a PyTorch file: {e}", path.display()))?;
        let pkl = (0..zip.len())
            .filter_map(|i| zip.name_for_index(i)?.ok().map(|n| n.into_owned()))
            .find(|n| n.ends_with("data.pkl"))
            .ok_or_else(|| {
                anyhow!(
                    "{} is a zip file but not a PyTorch file (no data.pkl)",
                    path.display()
                )
            })?;
        let mut pickle = Vec::new();
        zip.by_name(&pkl)?.read_to_end(&mut pickle)?;
        let mut stack = Stack::empty();
        stack
            .read_loop(&mut std::io::BufReader::new(&pickle[..]))
            .and_then(|()| stack.finalize())
            .map(|root| (root, pkl.clone()))
            .map_err(|e| anyhow!("{}: cannot unpickle {pkl}: {e}", path.display()))
            .map(|(root, pkl)| Self {
                path: path.to_path_buf(),
                zip,
                data_dir: PathBuf::from(pkl.strip_suffix(".pkl").unwrap_or(&pkl)),
                root,
            })
    }

    /// The file this archive was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The tensor `obj` describes, as f32 on the CPU (any shape), or `None` when `obj` is not
    /// a tensor. Contiguous tensors of float dtypes are supported.
    pub fn tensor(&mut self, obj: &Object) -> Result<Option<Tensor>> {
        let info = match obj
            .clone()
            .into_tensor_info(Object::Unicode(String::new()), &self.data_dir)
        {
            Ok(Some(info)) => info,
            _ => return Ok(None),
        };
        if !info.layout.is_contiguous() {
            bail!(
                "{}: a tensor is stored with strides {:?}; save a contiguous copy (.contiguous())",
                self.path.display(),
                info.layout.stride()
            );
        }
        let mut record = self
            .zip
            .by_name(&info.path)
            .with_context(|| format!("{}: record {} missing", self.path.display(), info.path))?;
        let mut bytes = Vec::new();
        record.read_to_end(&mut bytes)?;
        let start = info.layout.start_offset();
        let len = info.layout.shape().elem_count() * info.dtype.size_in_bytes();
        let data = bytes.get(start..start + len).ok_or_else(|| {
            anyhow!(
                "{}: record {} is shorter than its tensor",
                self.path.display(),
                info.path
            )
        })?;
        let t = Tensor::from_raw_buffer(data, info.dtype, info.layout.dims(), &Device::Cpu)?;
        Ok(Some(t.to_dtype(DType::F32)?))
    }
}

/// The key of the storage record a tensor object reads (`"0"`, `"1"`, …). `torch.save`
/// numbers storages in the order it pickles them, so for a state dict this is the
/// parameters' order (Candle's reader does not keep a dict's order: it reverses each batch
/// of `SETITEMS`).
pub fn storage_key(obj: &Object) -> Option<&str> {
    let Object::Reduce { args, .. } = obj else {
        return None;
    };
    let Object::Tuple(args) = args.as_ref() else {
        return None;
    };
    let Some(Object::PersistentLoad(id)) = args.first() else {
        return None;
    };
    match id.as_ref() {
        Object::Tuple(parts) => match parts.get(2) {
            Some(Object::Unicode(key)) => Some(key),
            _ => None,
        },
        _ => None,
    }
}

/// The value under string key `key` of a dict object.
pub fn dict_get<'a>(obj: &'a Object, key: &str) -> Option<&'a Object> {
    match obj {
        Object::Dict(entries) => entries
            .iter()
            .find(|(k, _)| matches!(k, Object::Unicode(s) if s == key))
            .map(|(_, v)| v),
        _ => None,
    }
}

/// An integer object's value (`int` or a `long`).
pub fn as_int(obj: &Object) -> Option<i64> {
    match obj {
        Object::Int(i) => Some(*i as i64),
        Object::Long(i) => Some(*i),
        _ => None,
    }
}

/// The file starts as a `torch.save` file does: a zip archive (`PK\x03\x04`), or a legacy
/// (pre-1.6) one ([`is_legacy_torch`]).
pub fn looks_like_torch(head: &[u8]) -> bool {
    head.starts_with(b"PK\x03\x04") || is_legacy_torch(head)
}

/// A legacy `torch.save` stream: pickle protocol 2 (`0x80 0x02`) whose first object is
/// PyTorch's magic number, a 10-byte `LONG1` (`0x8a 0x0a`).
pub fn is_legacy_torch(head: &[u8]) -> bool {
    head.starts_with(&[0x80, 0x02, 0x8a, 0x0a])
}
