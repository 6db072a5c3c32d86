//! Hostile PyTorch files: pickles written opcode by opcode and zip archives patched by hand.
//! A memo referenced again and again, nesting 100 000 deep, shapes that overflow or outrun
//! their storage, members that overlap or claim more bytes than the file has: each is refused
//! with one line (or read in bounded time and memory), never a panic, an abort or a stack
//! overflow.

use std::io::{Cursor, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use crate::pickle::{unpickle, MAX_DEPTH};
use crate::torch_archive::TorchArchive;

/// A pickle stream under construction.
#[derive(Default)]
struct Pickle(Vec<u8>);

impl Pickle {
    fn new() -> Self {
        Pickle(vec![0x80, 2])
    }
    fn op(&mut self, op: u8) -> &mut Self {
        self.0.push(op);
        self
    }
    /// The opcode `op`, `n` times.
    fn ops(&mut self, op: u8, n: usize) -> &mut Self {
        self.0.extend(std::iter::repeat_n(op, n));
        self
    }
    /// The opcode `op` followed by the bytes of its argument.
    fn op_with(&mut self, op: u8, argument: &[u8]) -> &mut Self {
        self.op(op);
        self.0.extend_from_slice(argument);
        self
    }
    fn put(&mut self, i: u32) -> &mut Self {
        self.op_with(b'r', &i.to_le_bytes())
    }
    fn get(&mut self, i: u32) -> &mut Self {
        self.op_with(b'j', &i.to_le_bytes())
    }
    fn int(&mut self, v: i32) -> &mut Self {
        self.op_with(b'J', &v.to_le_bytes())
    }
    fn long(&mut self, v: i64) -> &mut Self {
        self.op(0x8a).op_with(8, &v.to_le_bytes())
    }
    fn str(&mut self, s: &str) -> &mut Self {
        self.op_with(b'X', &(s.len() as u32).to_le_bytes());
        self.0.extend_from_slice(s.as_bytes());
        self
    }
    fn global(&mut self, module: &str, name: &str) -> &mut Self {
        self.op(b'c');
        self.0
            .extend_from_slice(format!("{module}\n{name}\n").as_bytes());
        self
    }
    fn ints(&mut self, v: &[i64]) -> &mut Self {
        self.op(b'(');
        for &x in v {
            self.long(x);
        }
        self.op(b't')
    }
    /// `torch._utils._rebuild_tensor_v2(storage, offset, shape, stride, False, {})` of a
    /// float storage `key` declaring `numel` elements.
    fn tensor(
        &mut self,
        key: &str,
        numel: i64,
        offset: i64,
        shape: &[i64],
        stride: &[i64],
    ) -> &mut Self {
        self.global("torch._utils", "_rebuild_tensor_v2").op(b'(');
        self.op(b'(')
            .str("storage")
            .global("torch", "FloatStorage")
            .str(key)
            .str("cpu");
        self.long(numel).op(b't').op(b'Q');
        self.long(offset)
            .ints(shape)
            .ints(stride)
            .op(0x89)
            .op(b'}')
            .op(b't')
            .op(b'R')
    }
    fn stop(&mut self) -> Vec<u8> {
        self.op(b'.');
        self.0.clone()
    }
}

/// A `torch.save`-style archive holding `pickle` as `archive/data.pkl` and the given records
/// as `archive/data/<key>`, stored.
fn archive(pickle: &[u8], records: &[(&str, Vec<u8>)]) -> Vec<u8> {
    let stored =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    zip.start_file("archive/data.pkl", stored).unwrap();
    zip.write_all(pickle).unwrap();
    for (key, bytes) in records {
        zip.start_file(format!("archive/data/{key}"), stored)
            .unwrap();
        zip.write_all(bytes).unwrap();
    }
    zip.finish().unwrap().into_inner()
}

/// `{"w": tensor}` as a pickle.
fn dict_of(tensor: impl FnOnce(&mut Pickle)) -> Vec<u8> {
    let mut p = Pickle::new();
    p.op(b'}').str("w");
    tensor(&mut p);
    p.op(b's').stop()
}

/// The error of opening `bytes` as a PyTorch file and reading its tensor `w`.
fn tensor_error(dir: &Path, bytes: &[u8]) -> String {
    let path = dir.join("t.pth");
    std::fs::write(&path, bytes).unwrap();
    let result = TorchArchive::open(&path).and_then(|mut a| {
        let w = a.root.get("w").expect("w");
        a.tensor(&w)
    });
    let err = format!("{:#}", result.expect_err("an error"));
    assert!(!err.contains('\n'), "not one line: {err}");
    err
}

fn floats(n: usize) -> Vec<u8> {
    (0..n).flat_map(|i| (i as f32).to_le_bytes()).collect()
}

#[test]
fn a_memo_referenced_again_and_again_is_shared_not_copied() {
    // Level i is a list of 16 references to level i-1: 16^40 objects if copied.
    let mut p = Pickle::new();
    p.op(b']').put(0).op(b'0');
    for i in 1..=40u32 {
        p.op(b'(');
        for _ in 0..16 {
            p.get(i - 1);
        }
        p.op(b'l').put(i).op(b'0');
    }
    p.get(40);
    let bytes = p.stop();
    assert!(bytes.len() < 4000);
    let start = Instant::now();
    let root = unpickle(&bytes).unwrap();
    assert_eq!(root.list().unwrap().len(), 16);
    drop(root);
    assert!(
        start.elapsed() < Duration::from_secs(1),
        "{:?}",
        start.elapsed()
    );
    // As a PyTorch file it is refused quickly for what it is (no state dict).
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bomb.pth");
    std::fs::write(&path, archive(&bytes, &[])).unwrap();
    let start = Instant::now();
    // Any parameters will do: the file has no state dict to hold them.
    let shapes = vec![("mlp.weight".to_string(), vec![4, 3])];
    let err = crate::torch::read_torch_checkpoint(&path, &shapes)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("no state dict"), "{err}");
    assert!(start.elapsed() < Duration::from_secs(1));
}

#[test]
fn a_memo_entry_sees_its_container_filled_later() {
    // Python's pickler memoizes a dict before filling it; a later reference is the full dict.
    let mut p = Pickle::new();
    p.op(b'}')
        .put(0)
        .op(b'(')
        .str("a")
        .int(1)
        .str("b")
        .int(2)
        .op(b'u');
    p.op(b'0').op(b'(').get(0).get(0).op(b'l');
    let root = unpickle(&p.stop()).unwrap();
    let items = root.list().unwrap();
    assert_eq!(items[1].get("b").and_then(|v| v.as_int()), Some(2));
}

#[test]
fn nesting_100k_deep_is_refused_without_overflowing_the_stack() {
    let n = 100_000;
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("lists", {
            let mut p = Pickle::new();
            p.ops(b']', n);
            p.ops(b'a', n - 1);
            p.stop()
        }),
        ("tuples", {
            let mut p = Pickle::new();
            p.op(b')');
            p.ops(0x85, n);
            p.stop()
        }),
        ("marks", {
            let mut p = Pickle::new();
            p.ops(b'(', n);
            p.ops(b't', n);
            p.stop()
        }),
        ("dicts", {
            let mut p = Pickle::new();
            p.op(b'}');
            for _ in 0..n {
                p.op(b'K').op(1).op(b'}');
            }
            p.ops(b's', n);
            p.stop()
        }),
    ];
    for (what, bytes) in cases {
        let start = Instant::now();
        let err = unpickle(&bytes).err().expect(what).to_string();
        assert!(
            err.contains(&format!("deeper than {MAX_DEPTH}")),
            "{what}: {err}"
        );
        assert!(!err.contains('\n'));
        assert!(start.elapsed() < Duration::from_secs(2), "{what}");
    }
}

#[test]
fn a_chain_deepened_through_the_memo_is_dropped_without_recursion() {
    // Lists 0..n, each memoized while empty; list i then gets list i-1 appended, from the
    // last to the first, so each is shallow when appended and the chain ends n deep.
    let n = 200_000u32;
    let mut p = Pickle::new();
    for i in 0..n {
        p.op(b']').put(i).op(b'0');
    }
    for i in (1..n).rev() {
        p.get(i).get(i - 1).op(b'a').op(b'0');
    }
    p.get(n - 1);
    let root = unpickle(&p.stop()).unwrap();
    // Walk it without recursion: it really is n deep.
    let mut depth = 1;
    let mut node = root.clone();
    loop {
        let next = node.list().unwrap().first().cloned();
        match next {
            Some(v) => {
                node = v;
                depth += 1;
            }
            None => break,
        }
    }
    assert_eq!(depth, n);
    drop(node);
    drop(root);
}

#[test]
fn malformed_streams_are_one_line_errors() {
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (vec![0x80, 2], "without STOP"),
        (vec![0x80, 2, b'X', 0xff, 0xff, 0xff, 0x7f], "bytes"),
        (vec![0x80, 2, b'h', 3, b'.'], "memo entry 3"),
        (vec![0x80, 2, b'a', b'.'], "empty"),
        (vec![0x80, 2, b'N', b'N', b'.'], "more than one"),
        (vec![0x80, 2, b'(', b'.'], "MARK"),
        (vec![0x80, 2, b'K', 1, b'K', 2, b'a', b'.'], "not a list"),
        (vec![0x80, 2, b'i', b'.'], "not supported"),
        (vec![0x80, 2, 0xfe, b'.'], "unknown"),
        (
            vec![
                0x80, 2, 0x8d, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff,
            ],
            "left",
        ),
    ];
    for (bytes, want) in cases {
        let err = unpickle(&bytes).err().expect(want).to_string();
        assert!(err.contains(want) && !err.contains('\n'), "{want}: {err}");
    }
}

#[test]
fn tensor_descriptions_are_checked_against_their_storage() {
    let dir = tempfile::tempdir().unwrap();
    // The well-formed one reads.
    let good = archive(
        &dict_of(|p| {
            p.tensor("0", 6, 0, &[2, 3], &[3, 1]);
        }),
        &[("0", floats(6))],
    );
    let path = dir.path().join("good.pth");
    std::fs::write(&path, &good).unwrap();
    let mut a = TorchArchive::open(&path).unwrap();
    let w = a.root.get("w").unwrap();
    let t = a.tensor(&w).unwrap().unwrap();
    assert_eq!(
        t.to_vec2::<f32>().unwrap(),
        vec![vec![0., 1., 2.], vec![3., 4., 5.]]
    );
    let cases: Vec<(Vec<u8>, Vec<u8>, &str)> = vec![
        (
            dict_of(|p| {
                p.tensor("0", 5, 0, &[2, 3], &[3, 1]);
            }),
            floats(6),
            "storage holds 5",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 1, &[2, 3], &[3, 1]);
            }),
            floats(6),
            "at offset 1 needs 7",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 0, &[2, 3], &[3, 1]);
            }),
            floats(5),
            "holds 20 bytes",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 0, &[1 << 62, 4], &[4, 1]);
            }),
            floats(6),
            "too large",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 1 << 62, 0, &[2, 3], &[3, 1]);
            }),
            floats(6),
            "declares",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, i64::MAX, &[2, 3], &[3, 1]);
            }),
            floats(6),
            "storage holds 6",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 0, &[-1, 3], &[3, 1]);
            }),
            floats(6),
            "is -1",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 0, &[2, 3], &[1, 2]);
            }),
            floats(6),
            "strides",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 0, &[2, 3], &[3]);
            }),
            floats(6),
            "1 strides",
        ),
        (
            dict_of(|p| {
                p.tensor("0", 6, 0, &[1; 65], &[1; 65]);
            }),
            floats(6),
            "more than 64",
        ),
        (
            dict_of(|p| {
                p.tensor("9", 6, 0, &[2, 3], &[3, 1]);
            }),
            floats(6),
            "archive/data/9",
        ),
    ];
    for (pickle, record, want) in cases {
        let err = tensor_error(dir.path(), &archive(&pickle, &[("0", record)]));
        assert!(err.contains(want), "{want}: {err}");
    }
}

#[test]
fn a_storage_shared_by_many_tensors_cannot_multiply_memory() {
    // 400 entries, each the same tensor over one 64 KiB storage (memoized once).
    let n = 16 << 10;
    let mut p = Pickle::new();
    p.op(b'}').op(b'(');
    p.str("t0").tensor("0", n, 0, &[n], &[1]).put(1);
    for i in 1..400 {
        p.str(&format!("t{i}")).get(1);
    }
    p.op(b'u');
    let bytes = archive(&p.stop(), &[("0", floats(n as usize))]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shared.pth");
    std::fs::write(&path, &bytes).unwrap();
    let mut a = TorchArchive::open(&path).unwrap();
    let mut read = 0;
    let err = loop {
        let t = a.root.get(&format!("t{read}")).unwrap();
        match a.tensor(&t) {
            Ok(_) => read += 1,
            Err(e) => break e.to_string(),
        }
    };
    assert!(err.contains("twice the file's size"), "{err}");
    // About (2 × 66 KB + 1 MiB) / 64 KiB of them fit.
    assert!((10..=25).contains(&read), "{read}");
}

/// Patches `zip`'s central directory: entry `index` copied `copies` more times (names made
/// distinct by their last byte), and the declared sizes of entry `index` set to `size`.
fn patch_central_directory(zip: &[u8], index: usize, copies: usize, size: Option<u32>) -> Vec<u8> {
    let eocd = zip.len() - 22;
    assert_eq!(&zip[eocd..eocd + 4], b"PK\x05\x06");
    let u16_at = |b: &[u8], i: usize| u16::from_le_bytes([b[i], b[i + 1]]) as usize;
    let u32_at = |b: &[u8], i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap()) as usize;
    let (count, cd_size, cd_start) = (
        u16_at(zip, eocd + 10),
        u32_at(zip, eocd + 12),
        u32_at(zip, eocd + 16),
    );
    let mut entries = Vec::new();
    let mut at = cd_start;
    for _ in 0..count {
        let len = 46 + u16_at(zip, at + 28) + u16_at(zip, at + 30) + u16_at(zip, at + 32);
        entries.push(zip[at..at + len].to_vec());
        at += len;
    }
    if let Some(size) = size {
        entries[index][20..24].copy_from_slice(&size.to_le_bytes());
        entries[index][24..28].copy_from_slice(&size.to_le_bytes());
    }
    for c in 0..copies {
        let mut e = entries[index].clone();
        let name_end = 46 + u16_at(&e, 28) - 1;
        e[name_end] = b'a' + (c % 26) as u8;
        e[name_end - 1] = b'a' + (c / 26) as u8;
        entries.push(e);
    }
    let cd: Vec<u8> = entries.concat();
    let mut out = zip[..cd_start].to_vec();
    out.extend_from_slice(&cd);
    let mut end = zip[eocd..].to_vec();
    let n = entries.len() as u16;
    end[8..10].copy_from_slice(&n.to_le_bytes());
    end[10..12].copy_from_slice(&n.to_le_bytes());
    end[12..16].copy_from_slice(&(cd.len() as u32).to_le_bytes());
    let _ = cd_size;
    out.extend_from_slice(&end);
    out
}

#[test]
fn overlapping_or_oversized_members_are_a_zip_bomb() {
    let dir = tempfile::tempdir().unwrap();
    let pickle = dict_of(|p| {
        p.tensor("0", 1 << 14, 0, &[1 << 14], &[1]);
    });
    let good = archive(&pickle, &[("0", floats(1 << 14))]);
    // 64 copies of the 64 KiB record's entry, all pointing at the same bytes.
    let bomb = patch_central_directory(&good, 1, 64, None);
    let err = tensor_error(dir.path(), &bomb);
    assert!(err.contains("zip bomb"), "{err}");
    // The record claiming a gigabyte it does not have.
    let liar = patch_central_directory(&good, 1, 0, Some(1 << 30));
    let err = tensor_error(dir.path(), &liar);
    assert!(err.contains("zip bomb"), "{err}");
    // Not a zip at all, a legacy stream, and a truncated archive.
    for (bytes, want) in [
        (b"hello".to_vec(), "not a PyTorch file"),
        (vec![0x80, 2, 0x8a, 0x0a, 0, 0], "legacy"),
        (good[..good.len() / 2].to_vec(), "not a PyTorch file"),
    ] {
        let err = tensor_error(dir.path(), &bytes);
        assert!(err.contains(want), "{want}: {err}");
    }
}
