//! Reading `torch.save` files: a zip archive holding `<name>/data.pkl` (the pickled object)
//! and `<name>/data/<key>` (each tensor storage's raw bytes). The object is read with our own
//! bounded pickle reader ([`crate::pickle`]) into a tree of shared [`Value`]s (dicts keep
//! their order, an `OrderedDict` included); a tensor in it is a
//! `torch._utils._rebuild_tensor_v2` call whose storage is a persistent id naming its record.
//!
//! Nothing read from the file is trusted: the archive's members and their declared sizes must
//! fit in the file (members may not overlap, so a few kilobytes cannot claim gigabytes), and a
//! tensor's shape, strides, offset and storage size are checked, with overflow-checked
//! arithmetic, against the record that holds it before anything is allocated. The tensors read
//! out hold at most twice the file's bytes (a storage shared by many tensors is not a way to
//! multiply memory).
//!
//! Legacy files (`torch.save(..., _use_new_zipfile_serialization=False)`, a bare pickle
//! stream) are refused with a message saying how to re-save them.

use std::collections::HashMap;
use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};
use std::rc::Rc;

use anyhow::{anyhow, bail, Result};
use candle_core::{DType, Device, Tensor};

use crate::pickle::{describe, unpickle, Value, MAX_PICKLE_BYTES};
use nerf_files::bounded_read::read_regular_file;

/// Largest `torch.save` file read.
pub(crate) const MAX_TORCH_FILE_BYTES: u64 = 4 << 30;
/// Most members of a `torch.save` archive (one per storage, and a few more).
pub(crate) const MAX_ARCHIVE_MEMBERS: usize = 1 << 20;
/// Most dimensions of a tensor.
const MAX_RANK: usize = 64;

/// An opened `torch.save` archive: its parsed object and its records.
pub(crate) struct TorchArchive {
    path: PathBuf,
    zip: zip::ZipArchive<Cursor<Vec<u8>>>,
    /// The records' folder inside the archive (`<name>/data`).
    data_dir: String,
    /// Records read so far, by name.
    records: HashMap<String, Rc<Vec<u8>>>,
    /// Bytes of tensor data that may still be read out.
    budget: usize,
    /// The unpickled object.
    pub root: Value,
}

/// Where a tensor's values lie: its storage record and its layout, all checked against each
/// other (not yet against the record's bytes).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TensorRef {
    /// The storage's key (`"0"`, `"1"`, …), naming record `<name>/data/<key>`.
    pub key: String,
    /// The element type.
    pub dtype: DType,
    /// Elements the storage holds, as the file declares.
    pub storage_len: usize,
    /// The first element's index in the storage.
    pub offset: usize,
    /// The tensor's shape.
    pub shape: Vec<usize>,
}

impl TensorRef {
    /// Elements of the tensor.
    pub(crate) fn elem_count(&self) -> usize {
        self.shape.iter().product()
    }
}

impl TorchArchive {
    /// Opens and unpickles `path`; an error (one line) names the file and what is wrong.
    pub(crate) fn open(path: &Path) -> Result<Self> {
        let bytes = read_regular_file(path, "PyTorch file", MAX_TORCH_FILE_BYTES)?;
        if is_legacy_torch(&bytes) {
            bail!(
                "{} is a legacy (non-zip) PyTorch file; re-save it with torch.save(obj, path) from PyTorch 1.6 or later",
                path.display()
            );
        }
        let file_len = bytes.len() as u64;
        let mut zip = zip::ZipArchive::new(Cursor::new(bytes))
            .map_err(|e| anyhow!("{} is not a PyTorch file: {}", path.display(), one_line(&e)))?;
        check_members(&mut zip, file_len).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        let pkl = (0..zip.len())
            .filter_map(|i| zip.name_for_index(i)?.ok().map(|n| n.into_owned()))
            .find(|n| n.ends_with("data.pkl"))
            .ok_or_else(|| {
                anyhow!(
                    "{} is a zip file but not a PyTorch file (no data.pkl)",
                    path.display()
                )
            })?;
        let pickle = read_member(&mut zip, &pkl, MAX_PICKLE_BYTES as u64)
            .map_err(|e| anyhow!("{}: {e}", path.display()))?;
        let root = unpickle(&pickle)
            .map_err(|e| anyhow!("{}: cannot unpickle {pkl}: {e}", path.display()))?;
        let budget = usize::try_from(file_len.saturating_mul(2))
            .unwrap_or(usize::MAX)
            .saturating_add(1 << 20);
        Ok(Self {
            path: path.to_path_buf(),
            zip,
            data_dir: pkl.strip_suffix(".pkl").unwrap_or(&pkl).to_string(),
            records: HashMap::new(),
            budget,
            root,
        })
    }

    /// The file this archive was read from.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// Reads every member through to its end, so that one whose stored CRC-32 does not match
    /// its bytes is an error naming it (PyTorch loads such files without a word).
    pub(crate) fn verify(&mut self) -> Result<()> {
        for i in 0..self.zip.len() {
            let mut member = self
                .zip
                .by_index(i)
                .map_err(|e| anyhow!("{}: member {i}: {}", self.path.display(), one_line(&e)))?;
            let name = member
                .name()
                .map_or_else(|_| format!("#{i}"), |n| n.to_string());
            std::io::copy(&mut member, &mut std::io::sink()).map_err(|e| {
                anyhow!(
                    "{}: member {name} is corrupt ({}); the file is damaged",
                    self.path.display(),
                    one_line(&e)
                )
            })?;
        }
        Ok(())
    }

    /// The tensor `obj` describes, as f32 on the CPU (any shape), or `None` when `obj` is not
    /// a tensor. Contiguous tensors of float (and u8, i64) storages are read; everything the
    /// file says about the tensor is checked against its record first.
    pub(crate) fn tensor(&mut self, obj: &Value) -> Result<Option<Tensor>> {
        let Some(t) = tensor_ref(obj).map_err(|e| anyhow!("{}: {e}", self.path.display()))? else {
            return Ok(None);
        };
        let size = t.dtype.size_in_bytes();
        let name = format!("{}/{}", self.data_dir, t.key);
        let record = match self.records.get(&name) {
            Some(r) => r.clone(),
            None => {
                let r = Rc::new(
                    read_member(&mut self.zip, &name, MAX_TORCH_FILE_BYTES)
                        .map_err(|e| anyhow!("{}: {e}", self.path.display()))?,
                );
                self.records.insert(name.clone(), r.clone());
                r
            }
        };
        // storage_len × size fits: tensor_ref checked it against isize::MAX.
        let declared = t.storage_len * size;
        if record.len() < declared {
            bail!(
                "{}: record {name} holds {} bytes, but its storage declares {} elements of {size} bytes",
                self.path.display(),
                record.len(),
                t.storage_len
            );
        }
        let start = t.offset * size;
        let len = t.elem_count() * size;
        if len > self.budget {
            bail!(
                "{}: its tensors add up to more than twice the file's size (storages shared by many tensors)",
                self.path.display()
            );
        }
        self.budget -= len;
        let data = &record[start..start + len];
        let tensor = Tensor::from_raw_buffer(data, t.dtype, &t.shape, &Device::Cpu)?;
        Ok(Some(tensor.to_dtype(DType::F32)?))
    }
}

/// The error's text on one line (zip and I/O errors are, but a newline would break the rule).
fn one_line(e: &dyn std::fmt::Display) -> String {
    e.to_string().replace(['\n', '\r'], " ")
}

/// Checks the archive's members against the file: at most [`MAX_ARCHIVE_MEMBERS`], each stored
/// (not compressed, as `torch.save` writes them) with its declared size equal to the bytes it
/// occupies, and all of them together no larger than the file (members may not overlap).
fn check_members(zip: &mut zip::ZipArchive<Cursor<Vec<u8>>>, file_len: u64) -> Result<()> {
    if zip.len() > MAX_ARCHIVE_MEMBERS {
        bail!(
            "the archive has {} members, more than {MAX_ARCHIVE_MEMBERS}",
            zip.len()
        );
    }
    let mut total = 0u64;
    for i in 0..zip.len() {
        let member = zip
            .by_index_raw(i)
            .map_err(|e| anyhow!("member {i}: {}", one_line(&e)))?;
        let (stored, size) = (member.compressed_size(), member.size());
        if member.compression() != zip::CompressionMethod::Stored {
            bail!(
                "member {i} is compressed ({}); torch.save stores its members uncompressed",
                member.compression()
            );
        }
        if stored != size {
            bail!("member {i} declares {size} bytes but occupies {stored}");
        }
        total = total.saturating_add(stored);
        if total > file_len {
            bail!(
                "its members declare {total} bytes or more, but the file is {file_len} bytes (a zip bomb or a damaged file)"
            );
        }
    }
    Ok(())
}

/// The bytes of member `name`, at most `max` of them (its declared size is checked first).
fn read_member(
    zip: &mut zip::ZipArchive<Cursor<Vec<u8>>>,
    name: &str,
    max: u64,
) -> Result<Vec<u8>> {
    let member = zip
        .by_name(name)
        .map_err(|e| anyhow!("record {name}: {}", one_line(&e)))?;
    let size = member.size();
    if size > max {
        bail!("record {name} declares {size} bytes, more than the {max} read");
    }
    let mut bytes = Vec::with_capacity(size as usize);
    member
        .take(size)
        .read_to_end(&mut bytes)
        .map_err(|e| anyhow!("record {name}: {}", one_line(&e)))?;
    if (bytes.len() as u64) < size {
        bail!(
            "record {name} declares {size} bytes but holds {}",
            bytes.len()
        );
    }
    Ok(bytes)
}

/// A non-negative integer from the file that fits in `usize`.
fn count(v: &Value, what: &str) -> Result<usize> {
    let i = v
        .as_int()
        .ok_or_else(|| anyhow!("a tensor's {what} is a {}, not an int", describe(v)))?;
    usize::try_from(i).map_err(|_| anyhow!("a tensor's {what} is {i}"))
}

/// The tensor call inside `obj`, unwrapping `torch._utils._rebuild_parameter(data, …)` and
/// `torch._tensor._rebuild_from_type_v2(func, type, args, state)` (a few levels at most).
fn rebuild_call(obj: &Value) -> Option<Value> {
    let mut obj = obj.clone();
    for _ in 0..4 {
        let (callable, args) = obj.reduce()?;
        let next = match callable.as_global()? {
            ("torch._utils", "_rebuild_tensor_v2") => return Some(args),
            ("torch._utils", "_rebuild_parameter" | "_rebuild_parameter_with_state") => {
                args.tuple()?.first()?.clone()
            }
            ("torch._tensor", "_rebuild_from_type_v2") => {
                let a = args.tuple()?;
                let (func, inner) = (a.first()?.clone(), a.get(2)?.clone());
                drop(a);
                if func.as_global() != Some(("torch._utils", "_rebuild_tensor_v2")) {
                    return None;
                }
                return Some(inner);
            }
            _ => return None,
        };
        obj = next;
    }
    None
}

/// What `obj` says about a tensor, checked: `None` when `obj` is not a tensor, an error (one
/// line) when it is one whose description does not hold together. `_rebuild_tensor_v2`'s
/// arguments are `(storage, storage_offset, size, stride, requires_grad, backward_hooks)`, the
/// storage a persistent id `('storage', StorageClass, key, location, numel)`.
pub(crate) fn tensor_ref(obj: &Value) -> Result<Option<TensorRef>> {
    let Some(args) = rebuild_call(obj) else {
        return Ok(None);
    };
    let args = args.tuple().ok_or_else(|| {
        anyhow!(
            "a tensor's arguments are a {}, not a tuple",
            describe(&args)
        )
    })?;
    if args.len() < 4 {
        bail!("a tensor has {} arguments, not 6", args.len());
    }
    let id = args[0].persistent_id().ok_or_else(|| {
        anyhow!(
            "a tensor's storage is a {}, not a record",
            describe(&args[0])
        )
    })?;
    let id = id
        .tuple()
        .ok_or_else(|| anyhow!("a storage id is a {}, not a tuple", describe(&id)))?;
    if id.len() < 5 || id[0].as_str() != Some("storage") {
        bail!("a storage id is not ('storage', class, key, location, size)");
    }
    let class = id[1].as_global().map(|(_, c)| c).unwrap_or("?");
    let dtype = match class {
        "FloatStorage" => DType::F32,
        "DoubleStorage" => DType::F64,
        "HalfStorage" => DType::F16,
        "BFloat16Storage" => DType::BF16,
        "ByteStorage" => DType::U8,
        "LongStorage" => DType::I64,
        other => bail!("storage type {other} is not supported (float tensors are read)"),
    };
    let key = id[2]
        .as_str()
        .ok_or_else(|| anyhow!("a storage key is a {}, not a str", describe(&id[2])))?
        .to_string();
    let storage_len = count(&id[4], "storage size")?;
    let offset = count(&args[1], "storage offset")?;
    let dims = |v: &Value, what: &str| -> Result<Vec<usize>> {
        let items = v
            .sequence()
            .ok_or_else(|| anyhow!("a tensor's {what} is a {}, not a tuple", describe(v)))?;
        if items.len() > MAX_RANK {
            bail!(
                "a tensor's {what} has {} dimensions, more than {MAX_RANK}",
                items.len()
            );
        }
        items.iter().map(|d| count(d, what)).collect()
    };
    let shape = dims(&args[2], "size")?;
    let stride = dims(&args[3], "stride")?;
    if shape.len() != stride.len() {
        bail!(
            "storage {key}: a tensor of {} dimensions has {} strides",
            shape.len(),
            stride.len()
        );
    }
    let too_big = || anyhow!("storage {key}: a tensor of shape {shape:?} is too large to address");
    let elems = shape
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .ok_or_else(too_big)?;
    let size = dtype.size_in_bytes();
    let bytes_of = |n: usize| n.checked_mul(size).filter(|&b| b <= isize::MAX as usize);
    bytes_of(storage_len)
        .ok_or_else(|| anyhow!("storage {key} declares {storage_len} elements"))?;
    bytes_of(elems).ok_or_else(too_big)?;
    // C-contiguous strides, dimensions of one element excepted (their stride is never used).
    let mut expected = 1usize;
    for (i, (&d, &s)) in shape.iter().zip(&stride).enumerate().rev() {
        if d != 1 && s != expected {
            bail!(
                "storage {key}: a tensor is stored with strides {stride:?} (dimension {i}); save a contiguous copy (.contiguous())"
            );
        }
        expected = expected.saturating_mul(d);
    }
    let end = offset.checked_add(elems).ok_or_else(too_big)?;
    if elems > 0 && end > storage_len {
        bail!(
            "storage {key}: a tensor of shape {shape:?} at offset {offset} needs {end} elements, but the storage holds {storage_len}"
        );
    }
    Ok(Some(TensorRef {
        key,
        dtype,
        storage_len,
        offset,
        shape,
    }))
}

#[cfg(test)]
/// The key of the storage record a tensor object reads (`"0"`, `"1"`, …). `torch.save`
/// numbers storages in the order it pickles them, so for a state dict this is the
/// parameters' order.
pub(crate) fn storage_key(obj: &Value) -> Option<String> {
    tensor_ref(obj).ok().flatten().map(|t| t.key)
}

#[cfg(test)]
/// The value under string key `key` of a dict object.
pub(crate) fn dict_get(obj: &Value, key: &str) -> Option<Value> {
    obj.get(key)
}

#[cfg(test)]
/// An integer object's value.
pub(crate) fn as_int(obj: &Value) -> Option<i64> {
    obj.as_int()
}

/// The file starts as a `torch.save` file does: a zip archive (`PK\x03\x04`), or a legacy
/// (pre-1.6) one ([`is_legacy_torch`]).
pub(crate) fn looks_like_torch(head: &[u8]) -> bool {
    head.starts_with(b"PK\x03\x04") || is_legacy_torch(head)
}

/// A legacy `torch.save` stream: pickle protocol 2 (`0x80 0x02`) whose first object is
/// PyTorch's magic number, a 10-byte `LONG1` (`0x8a 0x0a`).
pub(crate) fn is_legacy_torch(head: &[u8]) -> bool {
    head.starts_with(&[0x80, 0x02, 0x8a, 0x0a])
}
