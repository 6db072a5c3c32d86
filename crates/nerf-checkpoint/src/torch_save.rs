//! Writing `torch.save` files that `torch.load` (with its default `weights_only=True`) reads:
//! a zip archive of stored (uncompressed) records `archive/data.pkl` (the object, pickle
//! protocol 2), `archive/data/<i>` (each tensor's float32 little-endian bytes, aligned to
//! 64 bytes as PyTorch aligns them), `archive/byteorder` and `archive/version`.
//!
//! Only what a training checkpoint needs is written: dicts, `OrderedDict`s, lists, tuples,
//! strings, numbers, booleans, `None` and float32 tensors (`torch._utils._rebuild_tensor_v2`
//! of a `torch.FloatStorage`) — every global among those `torch.load`'s safe unpickler
//! allows.

use std::io::{Cursor, Write};
use std::path::Path;

use anyhow::Result;
use candle_core::{DType, Device, Tensor};

use nerf_files::output::write_atomically;

/// A Python value to pickle.
#[derive(Debug, Clone)]
pub(crate) enum PyValue {
    /// `None`.
    None,
    /// `True` / `False`.
    Bool(bool),
    /// An `int`.
    Int(i64),
    /// A `float`.
    Float(f64),
    /// A `str`.
    Str(String),
    /// A `tuple`.
    Tuple(Vec<PyValue>),
    /// A `list`.
    List(Vec<PyValue>),
    /// A `dict` in insertion order.
    Dict(Vec<(PyValue, PyValue)>),
    /// A `collections.OrderedDict` with string keys (what `state_dict()` returns).
    OrderedDict(Vec<(String, PyValue)>),
    /// A float32 CPU tensor of any shape (stored as its own record).
    Tensor(Tensor),
}

/// Pickle protocol 2 opcodes used here.
mod op {
    pub(crate) const PROTO: u8 = 0x80;
    pub(crate) const STOP: u8 = b'.';
    pub(crate) const MARK: u8 = b'(';
    pub(crate) const NONE: u8 = b'N';
    pub(crate) const NEWTRUE: u8 = 0x88;
    pub(crate) const NEWFALSE: u8 = 0x89;
    pub(crate) const BININT1: u8 = b'K';
    pub(crate) const BININT: u8 = b'J';
    pub(crate) const LONG1: u8 = 0x8a;
    pub(crate) const BINFLOAT: u8 = b'G';
    pub(crate) const BINUNICODE: u8 = b'X';
    pub(crate) const EMPTY_TUPLE: u8 = b')';
    pub(crate) const TUPLE: u8 = b't';
    pub(crate) const EMPTY_LIST: u8 = b']';
    pub(crate) const APPENDS: u8 = b'e';
    pub(crate) const EMPTY_DICT: u8 = b'}';
    pub(crate) const SETITEMS: u8 = b'u';
    pub(crate) const GLOBAL: u8 = b'c';
    pub(crate) const REDUCE: u8 = b'R';
    pub(crate) const BINPERSID: u8 = b'Q';
}

/// The pickle stream being written and the tensors it refers to (record `i` is tensor `i`).
struct Pickler {
    out: Vec<u8>,
    tensors: Vec<Vec<f32>>,
}

impl Pickler {
    fn global(&mut self, module: &str, name: &str) {
        self.out.push(op::GLOBAL);
        self.out
            .extend_from_slice(format!("{module}\n{name}\n").as_bytes());
    }

    fn int(&mut self, v: i64) {
        if (0..256).contains(&v) {
            self.out.extend([op::BININT1, v as u8]);
        } else if let Ok(v) = i32::try_from(v) {
            self.out.push(op::BININT);
            self.out.extend_from_slice(&v.to_le_bytes());
        } else {
            self.out.extend([op::LONG1, 8]);
            self.out.extend_from_slice(&v.to_le_bytes());
        }
    }

    fn str(&mut self, s: &str) {
        self.out.push(op::BINUNICODE);
        self.out.extend_from_slice(&(s.len() as u32).to_le_bytes());
        self.out.extend_from_slice(s.as_bytes());
    }

    fn tuple(&mut self, items: &[PyValue]) -> Result<()> {
        if items.is_empty() {
            self.out.push(op::EMPTY_TUPLE);
            return Ok(());
        }
        self.out.push(op::MARK);
        for v in items {
            self.value(v)?;
        }
        self.out.push(op::TUPLE);
        Ok(())
    }

    fn dict_items<'a>(
        &mut self,
        items: impl Iterator<Item = (PyValue, &'a PyValue)>,
    ) -> Result<()> {
        let mut items = items.peekable();
        if items.peek().is_none() {
            return Ok(());
        }
        self.out.push(op::MARK);
        for (k, v) in items {
            self.value(&k)?;
            self.value(v)?;
        }
        self.out.push(op::SETITEMS);
        Ok(())
    }

    /// `_rebuild_tensor_v2(storage, 0, size, stride, False, OrderedDict())`, the storage a
    /// persistent id `("storage", FloatStorage, key, "cpu", numel)`.
    fn tensor(&mut self, t: &Tensor) -> Result<()> {
        let dims: Vec<usize> = t.dims().to_vec();
        let values = t
            .to_device(&Device::Cpu)?
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        let key = self.tensors.len();
        let numel = values.len();
        self.tensors.push(values);
        let mut strides = vec![1i64; dims.len()];
        for i in (0..dims.len().saturating_sub(1)).rev() {
            strides[i] = strides[i + 1] * dims[i + 1] as i64;
        }
        self.global("torch._utils", "_rebuild_tensor_v2");
        self.out.push(op::MARK);
        self.out.push(op::MARK);
        self.str("storage");
        self.global("torch", "FloatStorage");
        self.str(&key.to_string());
        self.str("cpu");
        self.int(numel as i64);
        self.out.push(op::TUPLE);
        self.out.push(op::BINPERSID);
        self.int(0);
        let ints = |v: Vec<i64>| v.into_iter().map(PyValue::Int).collect::<Vec<_>>();
        self.tuple(&ints(dims.iter().map(|&d| d as i64).collect()))?;
        self.tuple(&ints(strides))?;
        self.out.push(op::NEWFALSE);
        self.global("collections", "OrderedDict");
        self.out.extend([op::EMPTY_TUPLE, op::REDUCE]);
        self.out.extend([op::TUPLE, op::REDUCE]);
        Ok(())
    }

    fn value(&mut self, v: &PyValue) -> Result<()> {
        match v {
            PyValue::None => self.out.push(op::NONE),
            PyValue::Bool(b) => self.out.push(if *b { op::NEWTRUE } else { op::NEWFALSE }),
            PyValue::Int(i) => self.int(*i),
            PyValue::Float(f) => {
                self.out.push(op::BINFLOAT);
                self.out.extend_from_slice(&f.to_be_bytes());
            }
            PyValue::Str(s) => self.str(s),
            PyValue::Tuple(items) => self.tuple(items)?,
            PyValue::List(items) => {
                self.out.push(op::EMPTY_LIST);
                if !items.is_empty() {
                    self.out.push(op::MARK);
                    for v in items {
                        self.value(v)?;
                    }
                    self.out.push(op::APPENDS);
                }
            }
            PyValue::Dict(items) => {
                self.out.push(op::EMPTY_DICT);
                self.dict_items(items.iter().map(|(k, v)| (k.clone(), v)))?;
            }
            PyValue::OrderedDict(items) => {
                self.global("collections", "OrderedDict");
                self.out.extend([op::EMPTY_TUPLE, op::REDUCE]);
                self.dict_items(items.iter().map(|(k, v)| (PyValue::Str(k.clone()), v)))?;
            }
            PyValue::Tensor(t) => self.tensor(t)?,
        }
        Ok(())
    }
}

/// The archive's bytes for `root`.
pub(crate) fn archive_bytes(root: &PyValue) -> Result<Vec<u8>> {
    let mut p = Pickler {
        out: vec![op::PROTO, 2],
        tensors: Vec::new(),
    };
    p.value(root)?;
    p.out.push(op::STOP);
    let stored = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .with_alignment(64);
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    zip.start_file("archive/data.pkl", stored)?;
    zip.write_all(&p.out)?;
    zip.start_file("archive/byteorder", stored)?;
    zip.write_all(b"little")?;
    for (i, values) in p.tensors.iter().enumerate() {
        zip.start_file(format!("archive/data/{i}"), stored)?;
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        zip.write_all(&bytes)?;
    }
    zip.start_file("archive/version", stored)?;
    zip.write_all(b"3\n")?;
    Ok(zip.finish()?.into_inner())
}

/// Writes `root` as a `torch.save` file at `path`, atomically.
pub(crate) fn torch_save(path: &Path, root: &PyValue) -> Result<()> {
    let bytes = archive_bytes(root)?;
    write_atomically(path, |w| Ok(w.write_all(&bytes)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::torch_archive::{as_int, dict_get, storage_key, TorchArchive};

    #[test]
    fn archives_read_back_with_their_tensors_order_and_values() {
        let (_dir, path) = nerf_files::test_files::temp_file("ckpt");
        let dev = &Device::Cpu;
        let a = Tensor::new(&[[1f32, 2.0, 3.0], [4.0, 5.0, 6.0]], dev).unwrap();
        let b = Tensor::new(7.5f32, dev).unwrap();
        let root = PyValue::Dict(vec![
            (
                PyValue::Str("model".into()),
                PyValue::OrderedDict(vec![
                    ("w".into(), PyValue::Tensor(a.clone())),
                    ("s".into(), PyValue::Tensor(b)),
                ]),
            ),
            (PyValue::Str("epoch".into()), PyValue::Int(70_000)),
            (PyValue::Str("neg".into()), PyValue::Int(-3)),
            (
                PyValue::Str("misc".into()),
                PyValue::List(vec![
                    PyValue::Float(0.25),
                    PyValue::Bool(true),
                    PyValue::None,
                    PyValue::Tuple(vec![]),
                ]),
            ),
        ]);
        torch_save(&path, &root).unwrap();
        assert!(std::fs::read(&path).unwrap().starts_with(b"PK\x03\x04"));
        let mut archive = TorchArchive::open(&path).unwrap();
        let r = archive.root.clone();
        assert_eq!(dict_get(&r, "epoch").and_then(|v| as_int(&v)), Some(70_000));
        assert_eq!(dict_get(&r, "neg").and_then(|v| as_int(&v)), Some(-3));
        let misc = dict_get(&r, "misc").unwrap();
        assert_eq!(misc.list().unwrap()[0].as_f64(), Some(0.25));
        let model = dict_get(&r, "model").unwrap();
        let w = dict_get(&model, "w").unwrap();
        assert_eq!(storage_key(&w).as_deref(), Some("0"));
        let back = archive.tensor(&w).unwrap().unwrap();
        assert_eq!(back.to_vec2::<f32>().unwrap(), a.to_vec2::<f32>().unwrap());
        let s = archive
            .tensor(&dict_get(&model, "s").unwrap())
            .unwrap()
            .unwrap();
        assert_eq!(s.dims(), &[] as &[usize]);
        assert_eq!(s.to_scalar::<f32>().unwrap(), 7.5);
    }
}
