//! A pickle reader with bounded resources, for the `data.pkl` of `torch.save` archives.
//!
//! Python objects are shared by reference, and so are ours: a memo entry (`BINPUT`, `MEMOIZE`)
//! and every later `BINGET` of it are the same [`Rc`], never a copy, so a stream that refers
//! to one object a million times holds it once. Lists and dicts are filled in place
//! (`APPENDS`, `SETITEMS`) as Python fills them, so a memo entry made before the container was
//! filled sees its items, as `pickle.load` does.
//!
//! Limits, each an error of one line naming the byte where it was hit:
//! * the stream is at most `MAX_PICKLE_BYTES` long and every length read from it (strings,
//!   bytes) must fit in what is left of it;
//! * at most `MAX_OPS` opcodes are run (each makes one object at most, so memory is bounded
//!   by a constant per opcode plus the stream's own bytes);
//! * no container nests deeper than [`MAX_DEPTH`]. Nothing here recurses over the tree
//!   (dropping one included, see [`Node`]'s `Drop`), so even a depth reached by mutating a
//!   container through the memo after it was nested cannot overflow the stack.
//!
//! A container made to hold itself (a list appended to itself through the memo) is not freed
//! until the process ends; what it holds is bounded by the stream, as everything is.
//!
//! Protocols 0 to 5 are read, except for the opcodes `torch.load`'s safe unpickler refuses as
//! well (`INST`, `OBJ`, the extension registry, out-of-band buffers). Globals are not
//! imported: a `GLOBAL` is a name, and `REDUCE` records the call without making it (except
//! `collections.OrderedDict()`, an empty dict).

use std::cell::{Cell, Ref, RefCell};
use std::collections::HashMap;
use std::rc::Rc;

use anyhow::{anyhow, bail, Result};

/// Longest pickle stream read (a state dict of thousands of tensors pickles to well under a
/// megabyte; the tensors themselves are records of their own).
pub(crate) const MAX_PICKLE_BYTES: usize = 64 << 20;
/// Most opcodes one stream may run (a state dict pickles to about 15 per tensor).
pub(crate) const MAX_OPS: usize = 1 << 21;
/// Deepest nesting of containers (a state dict is 4 deep).
pub(crate) const MAX_DEPTH: u32 = 1000;

/// An unpickled value. Containers are shared: cloning a [`Value`] clones an [`Rc`].
#[derive(Clone)]
// The payloads of `Bool`, `BigInt` and `Float` are not read: a checkpoint's structure needs
// ints, strings and containers, but the reader keeps every value a pickle holds, so that
// what it returns is the stream's whole content.
#[allow(dead_code)]
pub(crate) enum Value {
    /// `None`.
    None,
    /// `True` / `False`.
    Bool(bool),
    /// An `int` that fits in 64 bits.
    Int(i64),
    /// An `int` too large for 64 bits (kept as its little-endian two's-complement bytes).
    BigInt(Rc<[u8]>),
    /// A `float`.
    Float(f64),
    /// A `str`.
    Str(Rc<str>),
    /// A `bytes` or `bytearray` (or a protocol-0 `str` that is not UTF-8).
    Bytes(Rc<[u8]>),
    /// A global name, `module.name`, not imported.
    Global(Rc<(String, String)>),
    /// A tuple, list, dict, set, call or persistent id.
    Node(Rc<Node>),
}

/// What a [`Node`] is; its items are laid out as each variant says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    /// A tuple: its items.
    Tuple,
    /// A list: its items.
    List,
    /// A dict: keys and values alternating, in insertion order.
    Dict,
    /// A set or frozenset: its items.
    Set,
    /// `callable(*args)` (`REDUCE`, `NEWOBJ`): `[callable, args]`.
    Reduce,
    /// An object given state by `BUILD`: `[object, state]`.
    Build,
    /// A persistent id (`BINPERSID`): `[id]`.
    PersistentId,
}

/// A container value: its kind, its items and how deep it nests.
pub(crate) struct Node {
    kind: Kind,
    items: RefCell<Vec<Value>>,
    depth: Cell<u32>,
}

impl Drop for Node {
    /// Drops the tree below this node with a work list instead of recursion, so that no
    /// nesting depth overflows the stack.
    fn drop(&mut self) {
        let mut pending = std::mem::take(self.items.get_mut());
        while let Some(value) = pending.pop() {
            if let Value::Node(rc) = value {
                if let Ok(mut node) = Rc::try_unwrap(rc) {
                    pending.append(node.items.get_mut());
                }
            }
        }
    }
}

impl Value {
    /// The string, for a `str`.
    pub(crate) fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }

    /// The integer, for an `int` that fits in 64 bits (a `bool` is not one).
    pub(crate) fn as_int(&self) -> Option<i64> {
        match self {
            Value::Int(i) => Some(*i),
            _ => None,
        }
    }

    /// The number, for a `float` or an `int`.
    pub(crate) fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Float(f) => Some(*f),
            Value::Int(i) => Some(*i as f64),
            _ => None,
        }
    }

    /// `(module, name)`, for a global.
    pub(crate) fn as_global(&self) -> Option<(&str, &str)> {
        match self {
            Value::Global(g) => Some((&g.0, &g.1)),
            _ => None,
        }
    }

    /// The node, when this is a container of kind `kind`.
    fn node(&self, kind: Kind) -> Option<&Node> {
        match self {
            Value::Node(n) if n.kind == kind => Some(n),
            _ => None,
        }
    }

    /// The items, for a tuple.
    pub(crate) fn tuple(&self) -> Option<Ref<'_, Vec<Value>>> {
        self.node(Kind::Tuple).map(|n| n.items.borrow())
    }

    /// The items, for a list.
    pub(crate) fn list(&self) -> Option<Ref<'_, Vec<Value>>> {
        self.node(Kind::List).map(|n| n.items.borrow())
    }

    /// The items of a tuple or a list.
    pub(crate) fn sequence(&self) -> Option<Ref<'_, Vec<Value>>> {
        self.tuple().or_else(|| self.list())
    }

    /// The `(key, value)` pairs, in insertion order, for a dict.
    pub(crate) fn dict(&self) -> Option<Vec<(Value, Value)>> {
        self.node(Kind::Dict).map(|n| {
            n.items
                .borrow()
                .chunks_exact(2)
                .map(|kv| (kv[0].clone(), kv[1].clone()))
                .collect()
        })
    }

    /// The value under the string key `key`, for a dict (the last one set, as in Python).
    pub(crate) fn get(&self, key: &str) -> Option<Value> {
        let node = self.node(Kind::Dict)?;
        let items = node.items.borrow();
        items
            .chunks_exact(2)
            .rev()
            .find(|kv| kv[0].as_str() == Some(key))
            .map(|kv| kv[1].clone())
    }

    /// `(callable, args)`, for a `REDUCE` or `NEWOBJ`.
    pub(crate) fn reduce(&self) -> Option<(Value, Value)> {
        let node = self.node(Kind::Reduce)?;
        let items = node.items.borrow();
        Some((items[0].clone(), items[1].clone()))
    }

    /// The id, for a persistent id.
    pub(crate) fn persistent_id(&self) -> Option<Value> {
        let node = self.node(Kind::PersistentId)?;
        let id = node.items.borrow()[0].clone();
        Some(id)
    }

    /// How deep containers nest below and including this value (0 for a scalar).
    fn depth(&self) -> u32 {
        match self {
            Value::Node(n) => n.depth.get(),
            _ => 0,
        }
    }
}

/// Reads one pickled object from `bytes` (up to its `STOP`); see the module's limits.
pub(crate) fn unpickle(bytes: &[u8]) -> Result<Value> {
    if bytes.len() > MAX_PICKLE_BYTES {
        bail!(
            "the pickle is {} bytes, more than the {} read",
            bytes.len(),
            MAX_PICKLE_BYTES
        );
    }
    let mut m = Machine {
        input: bytes,
        pos: 0,
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
    };
    for ops in 0.. {
        if ops >= MAX_OPS {
            bail!("the pickle runs more than {MAX_OPS} opcodes");
        }
        let at = m.pos;
        let op = m.take(1).map_err(|_| anyhow!("pickle ends without STOP"))?[0];
        match m.step(op) {
            Ok(true) => break,
            Ok(false) => {}
            Err(e) => bail!("pickle opcode 0x{op:02x} at byte {at}: {e}"),
        }
    }
    if !m.marks.is_empty() {
        bail!("pickle stops with an open MARK");
    }
    match (m.stack.pop(), m.stack.is_empty()) {
        (Some(v), true) => Ok(v),
        (None, _) => bail!("pickle stops with nothing on its stack"),
        (Some(_), false) => bail!("pickle stops with more than one object on its stack"),
    }
}

/// The unpickling machine: input, stack, marks (stack heights at each `MARK`) and memo.
struct Machine<'a> {
    input: &'a [u8],
    pos: usize,
    stack: Vec<Value>,
    marks: Vec<usize>,
    memo: HashMap<u64, Value>,
}

impl<'a> Machine<'a> {
    /// The next `n` bytes of the stream; an error when fewer are left (checked before any
    /// allocation of `n`).
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let left = self.input.len() - self.pos;
        if n > left {
            bail!("needs {n} bytes, {left} are left");
        }
        let s = &self.input[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }

    fn le(&mut self, n: usize) -> Result<u64> {
        let b = self.take(n)?;
        Ok(b.iter().rev().fold(0u64, |acc, &x| (acc << 8) | x as u64))
    }

    /// A length of `n` little-endian bytes, as a count of bytes still to read.
    fn len(&mut self, n: usize) -> Result<usize> {
        let v = self.le(n)?;
        usize::try_from(v).map_err(|_| anyhow!("length {v} is too large"))
    }

    /// A protocol-0 argument: the bytes up to the next newline (dropped).
    fn line(&mut self) -> Result<&'a [u8]> {
        let rest = &self.input[self.pos..];
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| anyhow!("no newline ends its argument"))?;
        self.pos += end + 1;
        Ok(&rest[..end])
    }

    fn line_str(&mut self) -> Result<&'a str> {
        std::str::from_utf8(self.line()?).map_err(|_| anyhow!("its argument is not text"))
    }

    fn push(&mut self, v: Value) -> Result<()> {
        self.stack.push(v);
        Ok(())
    }

    fn pop(&mut self) -> Result<Value> {
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            bail!("the stack is empty");
        }
        Ok(self.stack.pop().expect("checked above"))
    }

    fn top(&self) -> Result<&Value> {
        let floor = self.marks.last().copied().unwrap_or(0);
        if self.stack.len() <= floor {
            bail!("the stack is empty");
        }
        Ok(self.stack.last().expect("checked above"))
    }

    /// The values above the last `MARK`, which is removed.
    fn pop_mark(&mut self) -> Result<Vec<Value>> {
        let mark = self.marks.pop().ok_or_else(|| anyhow!("no MARK"))?;
        Ok(self.stack.split_off(mark))
    }

    /// A new container of `kind` holding `items`; an error when it would nest too deep.
    fn node(&mut self, kind: Kind, items: Vec<Value>) -> Result<Value> {
        let depth = 1 + items.iter().map(Value::depth).max().unwrap_or(0);
        if depth > MAX_DEPTH {
            bail!("containers nest deeper than {MAX_DEPTH}");
        }
        Ok(Value::Node(Rc::new(Node {
            kind,
            items: RefCell::new(items),
            depth: Cell::new(depth),
        })))
    }

    /// Adds `items` to the list, dict or set on top of the stack (of kind `kind`).
    fn extend_top(&mut self, kind: Kind, items: Vec<Value>) -> Result<()> {
        let depth = 1 + items.iter().map(Value::depth).max().unwrap_or(0);
        let top = self.top()?;
        let node = top.node(kind).ok_or_else(|| {
            anyhow!(
                "adds items to a {}, not a {}",
                describe(top),
                format!("{kind:?}").to_lowercase()
            )
        })?;
        let depth = depth.max(node.depth.get());
        if depth > MAX_DEPTH {
            bail!("containers nest deeper than {MAX_DEPTH}");
        }
        node.depth.set(depth);
        node.items.borrow_mut().extend(items);
        Ok(())
    }

    /// The memo key of a GET or PUT opcode (`name`): a text line for `g`/`p`, one
    /// little-endian byte for `h`/`q`, four for `j`/`r`.
    fn memo_key(&mut self, op: u8, name: &str) -> Result<u64> {
        match op {
            b'h' | b'q' => self.le(1),
            b'j' | b'r' => self.le(4),
            _ => {
                let s = self.line_str()?.trim();
                s.parse().map_err(|_| anyhow!("bad {name} {s:?}"))
            }
        }
    }

    fn memo_get(&mut self, key: u64) -> Result<()> {
        let v = self
            .memo
            .get(&key)
            .cloned()
            .ok_or_else(|| anyhow!("memo entry {key} was never stored"))?;
        self.push(v)
    }

    fn memo_put(&mut self, key: u64) -> Result<()> {
        let v = self.top()?.clone();
        self.memo.insert(key, v);
        Ok(())
    }

    /// A string of `n` bytes, UTF-8.
    fn unicode(&mut self, n: usize) -> Result<()> {
        let s = std::str::from_utf8(self.take(n)?).map_err(|_| anyhow!("a str is not UTF-8"))?;
        self.push(Value::Str(Rc::from(s)))
    }

    /// Bytes of `n`; `text` keeps them as a str when they are UTF-8 (protocol 2's `str`).
    fn bytes(&mut self, n: usize, text: bool) -> Result<()> {
        let b = self.take(n)?;
        let v = match (text, std::str::from_utf8(b)) {
            (true, Ok(s)) => Value::Str(Rc::from(s)),
            _ => Value::Bytes(Rc::from(b)),
        };
        self.push(v)
    }

    /// A little-endian two's-complement integer of `n` bytes.
    fn long(&mut self, n: usize) -> Result<()> {
        let b = self.take(n)?;
        let v = if n == 0 {
            Value::Int(0)
        } else if n <= 8 {
            let negative = b[n - 1] & 0x80 != 0;
            let mut raw = [if negative { 0xff } else { 0 }; 8];
            raw[..n].copy_from_slice(b);
            Value::Int(i64::from_le_bytes(raw))
        } else {
            Value::BigInt(Rc::from(b))
        };
        self.push(v)
    }

    fn global(&mut self, module: &str, name: &str) -> Result<()> {
        self.push(Value::Global(Rc::new((
            module.to_string(),
            name.to_string(),
        ))))
    }

    /// `callable(*args)`: recorded, except `collections.OrderedDict()`, an empty dict.
    fn reduce(&mut self, callable: Value, args: Value) -> Result<()> {
        let ordered_dict = matches!(
            callable.as_global(),
            Some(("collections", "OrderedDict" | "defaultdict"))
        );
        let v = if ordered_dict {
            self.node(Kind::Dict, Vec::new())?
        } else {
            self.node(Kind::Reduce, vec![callable, args])?
        };
        self.push(v)
    }

    /// Runs opcode `op`; `Ok(true)` at `STOP`.
    fn step(&mut self, op: u8) -> Result<bool> {
        match op {
            b'.' => return Ok(true),
            0x80 => {
                let proto = self.u8()?;
                if proto > 5 {
                    bail!("unsupported protocol {proto}");
                }
            }
            // FRAME: a length hint only.
            0x95 => {
                self.take(8)?;
            }
            b'(' => {
                self.marks.push(self.stack.len());
            }
            b'0' => {
                self.pop()?;
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => {
                let v = self.top()?.clone();
                self.push(v)?;
            }
            b'N' => self.push(Value::None)?,
            0x88 => self.push(Value::Bool(true))?,
            0x89 => self.push(Value::Bool(false))?,
            b'I' => {
                let v = match self.line_str()?.trim() {
                    "00" => Value::Bool(false),
                    "01" => Value::Bool(true),
                    s => Value::Int(s.parse().map_err(|_| anyhow!("bad INT {s:?}"))?),
                };
                self.push(v)?
            }
            b'J' => {
                let v = self.le(4)? as u32 as i32;
                self.push(Value::Int(v as i64))?
            }
            b'K' => {
                let v = self.u8()?;
                self.push(Value::Int(v as i64))?
            }
            b'M' => {
                let v = self.le(2)?;
                self.push(Value::Int(v as i64))?
            }
            b'L' => {
                let s = self.line_str()?.trim();
                let s = s.strip_suffix('L').unwrap_or(s);
                let v = s.parse().map_err(|_| anyhow!("bad LONG {s:?}"))?;
                self.push(Value::Int(v))?
            }
            // LONG1, LONG4
            0x8a | 0x8b => {
                let n = self.len(length_width(op))?;
                self.long(n)?
            }
            b'F' => {
                let s = self.line_str()?.trim();
                let v = s.parse().map_err(|_| anyhow!("bad FLOAT {s:?}"))?;
                self.push(Value::Float(v))?
            }
            b'G' => {
                let v = f64::from_bits(u64::from_be_bytes(
                    self.take(8)?.try_into().expect("8 bytes"),
                ));
                self.push(Value::Float(v))?
            }
            b'S' => {
                let s = self.line()?;
                let inner = s
                    .strip_prefix(b"'")
                    .and_then(|s| s.strip_suffix(b"'"))
                    .or_else(|| s.strip_prefix(b"\"").and_then(|s| s.strip_suffix(b"\"")))
                    .ok_or_else(|| anyhow!("STRING argument is not quoted"))?;
                let v = match std::str::from_utf8(inner) {
                    Ok(s) => Value::Str(Rc::from(s)),
                    Err(_) => Value::Bytes(Rc::from(inner)),
                };
                self.push(v)?
            }
            b'V' => {
                let s = String::from_utf8_lossy(self.line()?).into_owned();
                self.push(Value::Str(Rc::from(s)))?
            }
            // BINSTRING, SHORT_BINSTRING (Python 2 strings: text when UTF-8)
            b'T' | b'U' => {
                let n = self.len(length_width(op))?;
                self.bytes(n, true)?
            }
            // BINUNICODE, SHORT_BINUNICODE, BINUNICODE8
            b'X' | 0x8c | 0x8d => {
                let n = self.len(length_width(op))?;
                self.unicode(n)?
            }
            // BINBYTES, SHORT_BINBYTES, BINBYTES8, BYTEARRAY8
            b'B' | b'C' | 0x8e | 0x96 => {
                let n = self.len(length_width(op))?;
                self.bytes(n, false)?
            }
            // EMPTY_TUPLE, EMPTY_LIST, EMPTY_DICT, EMPTY_SET
            b')' | b']' | b'}' | 0x8f => {
                let kind = match op {
                    b')' => Kind::Tuple,
                    b']' => Kind::List,
                    b'}' => Kind::Dict,
                    _ => Kind::Set,
                };
                let v = self.node(kind, Vec::new())?;
                self.push(v)?
            }
            // TUPLE, LIST, FROZENSET: the items since the mark
            b't' | b'l' | 0x91 => {
                let kind = match op {
                    b't' => Kind::Tuple,
                    b'l' => Kind::List,
                    _ => Kind::Set,
                };
                let items = self.pop_mark()?;
                let v = self.node(kind, items)?;
                self.push(v)?
            }
            0x85..=0x87 => {
                let n = (op - 0x84) as usize;
                let mut items = (0..n).map(|_| self.pop()).collect::<Result<Vec<_>>>()?;
                items.reverse();
                let v = self.node(Kind::Tuple, items)?;
                self.push(v)?
            }
            b'a' => {
                let v = self.pop()?;
                self.extend_top(Kind::List, vec![v])?
            }
            b'e' => {
                let items = self.pop_mark()?;
                self.extend_top(Kind::List, items)?
            }
            b'd' => {
                let items = self.pop_mark()?;
                if !items.len().is_multiple_of(2) {
                    bail!("a dict of an odd number of keys and values");
                }
                let v = self.node(Kind::Dict, items)?;
                self.push(v)?
            }
            b's' => {
                let value = self.pop()?;
                let key = self.pop()?;
                self.extend_top(Kind::Dict, vec![key, value])?
            }
            b'u' => {
                let items = self.pop_mark()?;
                if !items.len().is_multiple_of(2) {
                    bail!("SETITEMS of an odd number of keys and values");
                }
                self.extend_top(Kind::Dict, items)?
            }
            0x90 => {
                let items = self.pop_mark()?;
                self.extend_top(Kind::Set, items)?
            }
            b'g' | b'h' | b'j' => {
                let key = self.memo_key(op, "GET")?;
                self.memo_get(key)?
            }
            b'p' | b'q' | b'r' => {
                let key = self.memo_key(op, "PUT")?;
                self.memo_put(key)?
            }
            0x94 => {
                let key = self.memo.len() as u64;
                self.memo_put(key)?
            }
            b'c' => {
                let module = self.line_str()?;
                let name = self.line_str()?;
                self.global(module, name)?
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                match (module.as_str(), name.as_str()) {
                    (Some(m), Some(n)) => self.global(m, n)?,
                    _ => bail!("STACK_GLOBAL of names that are not strings"),
                }
            }
            // REDUCE, NEWOBJ, NEWOBJ_EX (whose keyword arguments are dropped): a callable or
            // class and its arguments
            b'R' | 0x81 | 0x92 => {
                if op == 0x92 {
                    self.pop()?;
                }
                let args = self.pop()?;
                let callable = self.pop()?;
                self.reduce(callable, args)?
            }
            b'b' => {
                let state = self.pop()?;
                let object = self.pop()?;
                // A dict's state is attributes (an OrderedDict's `_metadata`), not items:
                // the dict stays as it is.
                let v = if object.node(Kind::Dict).is_some() {
                    object
                } else {
                    self.node(Kind::Build, vec![object, state])?
                };
                self.push(v)?
            }
            b'P' => {
                let id = String::from_utf8_lossy(self.line()?).into_owned();
                let v = self.node(Kind::PersistentId, vec![Value::Str(Rc::from(id))])?;
                self.push(v)?
            }
            b'Q' => {
                let id = self.pop()?;
                let v = self.node(Kind::PersistentId, vec![id])?;
                self.push(v)?
            }
            b'i' | b'o' | 0x82..=0x84 | 0x97 | 0x98 => {
                bail!("not supported (torch.save does not write it)")
            }
            _ => bail!("unknown opcode"),
        }
        Ok(false)
    }
}

/// A few words for what `v` is, for error messages.
pub(crate) fn describe(v: &Value) -> &'static str {
    match v {
        Value::None => "None",
        Value::Bool(_) => "bool",
        Value::Int(_) | Value::BigInt(_) => "int",
        Value::Float(_) => "float",
        Value::Str(_) => "str",
        Value::Bytes(_) => "bytes",
        Value::Global(_) => "global",
        Value::Node(n) => match n.kind {
            Kind::Tuple => "tuple",
            Kind::List => "list",
            Kind::Dict => "dict",
            Kind::Set => "set",
            Kind::Reduce => "object",
            Kind::Build => "object",
            Kind::PersistentId => "persistent id",
        },
    }
}

/// Bytes of the little-endian length that follows a length-prefixed opcode: 1 for the
/// SHORT_ forms (and LONG1), 8 for the protocol 4 forms (`…8`), 4 for the rest.
fn length_width(op: u8) -> usize {
    match op {
        0x8a | b'U' | 0x8c | b'C' => 1,
        0x8d | 0x8e | 0x96 => 8,
        _ => 4,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes_of(hex: &str) -> Vec<u8> {
        (0..hex.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
            .collect()
    }

    /// Written by CPython 3's `pickle.dumps(obj, protocol=5)` for `obj = ([], (), {}, set(),
    /// frozenset({1}), b"ab", bytearray(b"cd"), "ü", 2**70, [1, 2], (3, 4, 5, 6),
    /// collections.OrderedDict())`: the EMPTY_* opcodes, FROZENSET, TUPLE, SHORT_BINBYTES,
    /// BYTEARRAY8, SHORT_BINUNICODE, LONG1 and REDUCE.
    #[test]
    fn protocol_5_containers_strings_and_numbers_read_as_python_wrote_them() {
        let data = bytes_of(concat!(
            "8005956500000000000000285d94297d948f94284b01919443026162949602000000000000006364",
            "948c02c3bc948a090000000000000000405d94284b014b0265284b034b044b054b0674948c0b636f",
            "6c6c656374696f6e73948c0b4f7264657265644469637494939429529474942e"
        ));
        let v = unpickle(&data).unwrap();
        let items = v.tuple().unwrap();
        assert_eq!(items.len(), 12);
        assert!(items[0].list().unwrap().is_empty());
        assert!(items[1].tuple().unwrap().is_empty());
        assert!(items[2].dict().unwrap().is_empty());
        let set = |v: &Value| v.node(Kind::Set).map(|n| n.items.borrow().len());
        assert_eq!(set(&items[3]), Some(0));
        assert_eq!(set(&items[4]), Some(1));
        assert!(matches!(&items[5], Value::Bytes(b) if &b[..] == b"ab"));
        assert!(matches!(&items[6], Value::Bytes(b) if &b[..] == b"cd"));
        assert_eq!(items[7].as_str(), Some("ü"));
        // 2^70 does not fit in 64 bits: its 9 little-endian bytes.
        assert!(matches!(&items[8], Value::BigInt(b) if b[..] == [0, 0, 0, 0, 0, 0, 0, 0, 0x40]));
        let ints = |v: &Value| -> Vec<i64> {
            v.sequence()
                .unwrap()
                .iter()
                .map(|i| i.as_int().unwrap())
                .collect()
        };
        assert_eq!(ints(&items[9]), [1, 2]);
        assert_eq!(ints(&items[10]), [3, 4, 5, 6]);
        // REDUCE of `collections.OrderedDict` on no arguments: an empty dict.
        assert!(items[11].dict().unwrap().is_empty());
    }

    /// CPython 3's pickles of a `__main__` class instance: protocol 2 (GLOBAL, NEWOBJ, BUILD
    /// with the instance dict) and protocol 4 with `__getnewargs_ex__` returning `((7,),
    /// {"k": 8})` (NEWOBJ_EX: the keyword arguments are dropped).
    #[test]
    fn newobj_and_newobj_ex_read_as_calls_of_the_class() {
        let v2 = "8002635f5f6d61696e5f5f0a4b0a7100298171017d710258010000006171034b0173622e";
        let v2 = unpickle(&bytes_of(v2)).unwrap();
        let build = v2.node(Kind::Build).unwrap().items.borrow().clone();
        let (class, args) = build[0].reduce().unwrap();
        assert_eq!(class.as_global(), Some(("__main__", "K")));
        assert!(args.tuple().unwrap().is_empty());
        assert_eq!(build[1].get("a").and_then(|a| a.as_int()), Some(1));

        let v4 = unpickle(&bytes_of(concat!(
            "80049521000000000000008c085f5f6d61696e5f5f948c01459493944b0785947d948c016b944b08",
            "7392942e"
        )))
        .unwrap();
        let (class, args) = v4.reduce().unwrap();
        assert_eq!(class.as_global(), Some(("__main__", "E")));
        let args = args.tuple().unwrap();
        assert_eq!(args.len(), 1);
        assert_eq!(args[0].as_int(), Some(7));
    }
}
