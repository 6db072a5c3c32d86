//! Reading `.npy` images: the homework's training targets (`np.save` of an `(H, W, 3)`
//! float array, read there with `np.load`).
//!
//! The header (a Python dict literal such as `{'descr': '<f4', 'fortran_order': False,
//! 'shape': (2, 3, 3), }`) is read by a parser of our own that looks at each byte once, with
//! the header's length limited to [`MAX_HEADER_BYTES`] (numpy's own limit is 10 000); the
//! shape's element count is computed with overflow checks and must match the data's length
//! exactly before anything is allocated for it.

use std::path::Path;

use anyhow::{anyhow, bail, Result};

use crate::bounded_read::read_regular_file;
use nerf_core::image::RgbImage;

/// Longest header read.
pub const MAX_HEADER_BYTES: usize = 1 << 16;

/// What a `.npy` header says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NpyHeader {
    /// The dtype string (`<f4`, `<f8`, …).
    pub descr: String,
    /// Whether the data is in Fortran (column-major) order.
    pub fortran_order: bool,
    /// The array's shape.
    pub shape: Vec<u64>,
    /// Where the data starts in the file.
    pub data_offset: usize,
}

/// Parses the magic, version and header dict of a `.npy` file's bytes. Errors (one line)
/// for anything that is not a well-formed header of versions 1 to 3.
pub fn parse_npy_header(bytes: &[u8]) -> Result<NpyHeader> {
    let rest = bytes
        .strip_prefix(b"\x93NUMPY")
        .ok_or_else(|| anyhow!("no .npy magic number"))?;
    let (&major, rest) = rest
        .split_first()
        .ok_or_else(|| anyhow!("truncated header"))?;
    let rest = rest.get(1..).ok_or_else(|| anyhow!("truncated header"))?;
    let (len_bytes, start) = match major {
        1 => (2, 10),
        2 | 3 => (4, 12),
        v => bail!("format version {v} is not 1, 2 or 3"),
    };
    let len = rest
        .get(..len_bytes)
        .ok_or_else(|| anyhow!("truncated header"))?
        .iter()
        .rev()
        .fold(0usize, |acc, &b| (acc << 8) | b as usize);
    if len > MAX_HEADER_BYTES {
        bail!("header of {len} bytes, more than the {MAX_HEADER_BYTES} read");
    }
    let header = bytes
        .get(start..start + len)
        .ok_or_else(|| anyhow!("truncated header ({len} bytes declared)"))?;
    let text = std::str::from_utf8(header).map_err(|_| anyhow!("header is not text"))?;
    let (descr, fortran_order, shape) = Lexer {
        s: text.as_bytes(),
        i: 0,
    }
    .dict()?;
    Ok(NpyHeader {
        descr,
        fortran_order,
        shape,
        data_offset: start + len,
    })
}

/// A single-pass reader of the header's dict literal.
struct Lexer<'a> {
    s: &'a [u8],
    i: usize,
}

impl Lexer<'_> {
    fn skip_space(&mut self) {
        while self.s.get(self.i).is_some_and(|b| b.is_ascii_whitespace()) {
            self.i += 1;
        }
    }

    /// Consumes `c` (after spaces) when it is next.
    fn eat(&mut self, c: u8) -> bool {
        self.skip_space();
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            true
        } else {
            false
        }
    }

    fn expect(&mut self, c: u8) -> Result<()> {
        if !self.eat(c) {
            bail!("header: expected `{}` at byte {}", c as char, self.i);
        }
        Ok(())
    }

    /// A quoted string without escapes.
    fn string(&mut self) -> Result<String> {
        self.skip_space();
        let quote = match self.s.get(self.i) {
            Some(&q @ (b'\'' | b'"')) => q,
            _ => bail!("header: expected a quoted string at byte {}", self.i),
        };
        let start = self.i + 1;
        let len = self.s[start..]
            .iter()
            .position(|&b| b == quote)
            .ok_or_else(|| anyhow!("header: unterminated string"))?;
        self.i = start + len + 1;
        let s = std::str::from_utf8(&self.s[start..start + len]).expect("from a str");
        if s.contains('\\') {
            bail!("header: escapes in strings are not supported");
        }
        Ok(s.to_string())
    }

    fn word(&mut self) -> &str {
        self.skip_space();
        let start = self.i;
        while self.s.get(self.i).is_some_and(u8::is_ascii_alphanumeric) {
            self.i += 1;
        }
        std::str::from_utf8(&self.s[start..self.i]).expect("ASCII")
    }

    /// `(d0, d1, …)` of non-negative integers (a trailing comma allowed, `L` suffixes of
    /// Python 2 too).
    fn shape(&mut self) -> Result<Vec<u64>> {
        self.expect(b'(')?;
        let mut dims = Vec::new();
        loop {
            if self.eat(b')') {
                return Ok(dims);
            }
            let w = self.word();
            let digits = w.strip_suffix('L').unwrap_or(w);
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                bail!("header: shape entry `{w}` is not a whole number");
            }
            let d = digits
                .parse::<u64>()
                .map_err(|_| anyhow!("header: shape entry {digits} is too large"))?;
            dims.push(d);
            if dims.len() > 64 {
                bail!("header: shape has more than 64 dimensions");
            }
            if !self.eat(b',') {
                self.expect(b')')?;
                return Ok(dims);
            }
        }
    }

    /// The dict: `descr`, `fortran_order` and `shape`, each exactly once.
    fn dict(mut self) -> Result<(String, bool, Vec<u64>)> {
        self.expect(b'{')?;
        let (mut descr, mut order, mut shape) = (None, None, None);
        loop {
            if self.eat(b'}') {
                break;
            }
            let key = self.string()?;
            self.expect(b':')?;
            let seen = match key.as_str() {
                "descr" => descr.replace(self.string()?).is_some(),
                "fortran_order" => {
                    let v = match self.word() {
                        "True" => true,
                        "False" => false,
                        w => bail!("header: fortran_order is `{w}`, not True or False"),
                    };
                    order.replace(v).is_some()
                }
                "shape" => shape.replace(self.shape()?).is_some(),
                other => bail!("header: unknown key {other:?}"),
            };
            if seen {
                bail!("header: key {key:?} given twice");
            }
            if !self.eat(b',') {
                self.expect(b'}')?;
                break;
            }
        }
        if self.s[self.i..].iter().any(|b| !b.is_ascii_whitespace()) {
            bail!("header: text after the dict");
        }
        Ok((
            descr.ok_or_else(|| anyhow!("header: no descr"))?,
            order.ok_or_else(|| anyhow!("header: no fortran_order"))?,
            shape.ok_or_else(|| anyhow!("header: no shape"))?,
        ))
    }
}

/// Reads a C-ordered float32 (or float64) `.npy` array of shape `(height, width, 3)` as an
/// image. An error names the file and what is wrong: missing or unreadable, not a `.npy`,
/// another shape, dtype or order, data of another length, or a NaN or infinite value.
pub fn read_npy_image(path: &Path, width: usize, height: usize) -> Result<RgbImage> {
    // The largest file such an image can be: a float64 array and the longest header.
    let max = (height as u64)
        .checked_mul(width as u64)
        .and_then(|n| n.checked_mul(3 * 8))
        .and_then(|n| n.checked_add(MAX_HEADER_BYTES as u64 + 12))
        .ok_or_else(|| anyhow!("image size {width}x{height} is too large"))?;
    let bytes = read_regular_file(path, ".npy image", max)?;
    let npy = parse_npy_header(&bytes)
        .map_err(|e| anyhow!("{} is not a .npy array: {e}", path.display()))?;
    let want = [height as u64, width as u64, 3];
    if npy.shape != want {
        bail!(
            "{}: shape {:?}, but data.image_size [{width}, {height}] needs ({height}, {width}, 3)",
            path.display(),
            npy.shape
        );
    }
    if npy.fortran_order {
        bail!(
            "{}: a Fortran-ordered array; save it with np.save(path, np.ascontiguousarray(a))",
            path.display()
        );
    }
    let item = match npy.descr.as_str() {
        "<f4" => 4,
        "<f8" => 8,
        other => bail!(
            "{}: dtype {other}, but a float32 image is expected",
            path.display()
        ),
    };
    let data = &bytes[npy.data_offset..];
    // The shape is the image's, whose byte count `max` above already bounds.
    let need = height * width * 3 * item;
    if data.len() != need {
        bail!(
            "{}: {} bytes of data, but shape {:?} of {} needs {need}",
            path.display(),
            data.len(),
            npy.shape,
            npy.descr
        );
    }
    let values: Vec<f32> = if item == 4 {
        data.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect()
    } else {
        data.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
            .collect()
    };
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        bail!(
            "{}: value {} at index {i} is not finite",
            path.display(),
            values[i]
        );
    }
    RgbImage::new(width, height, values)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::images::write_npy;
    use std::time::{Duration, Instant};

    /// A `.npy` file as numpy writes it: version 1.0, the header dict padded with spaces to a
    /// multiple of 64 bytes and ended with a newline.
    fn numpy_file(dict: &str, data: &[u8]) -> Vec<u8> {
        let mut header = dict.to_string();
        while !(10 + header.len() + 1).is_multiple_of(64) {
            header.push(' ');
        }
        header.push('\n');
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(data);
        out
    }

    #[test]
    fn round_trips_and_names_bad_shapes() {
        let (dir, p) = crate::test_files::temp_file("t.npy");
        let values: Vec<f32> = (0..2 * 3 * 3).map(|i| i as f32 / 18.0).collect();
        write_npy(&p, &[2, 3, 3], &values).unwrap();
        let img = read_npy_image(&p, 3, 2).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.data, values);
        let err = read_npy_image(&p, 2, 3).unwrap_err().to_string();
        assert!(
            err.contains("shape [2, 3, 3]") && err.contains("(3, 2, 3)"),
            "{err}"
        );
        let missing = read_npy_image(&dir.path().join("none.npy"), 3, 2).unwrap_err();
        assert!(format!("{missing:#}").contains("none.npy"));
        std::fs::write(&p, b"not an array").unwrap();
        assert!(read_npy_image(&p, 3, 2)
            .unwrap_err()
            .to_string()
            .contains("not a .npy"));
        let mut nan = values.clone();
        nan[4] = f32::NAN;
        write_npy(&p, &[2, 3, 3], &nan).unwrap();
        assert!(read_npy_image(&p, 3, 2)
            .unwrap_err()
            .to_string()
            .contains("not finite"));
    }

    #[test]
    fn numpy_written_headers_read_in_every_version_and_dtype() {
        let values: Vec<f64> = (0..6).map(|i| i as f64 * 0.125).collect();
        let f8: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let file = numpy_file(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 1, 3), }",
            &f8,
        );
        let h = parse_npy_header(&file).unwrap();
        assert_eq!(h.shape, vec![2, 1, 3]);
        assert_eq!(h.descr, "<f8");
        assert_eq!(h.data_offset % 64, 0);
        let (_dir, p) = crate::test_files::temp_file("a.npy");
        std::fs::write(&p, &file).unwrap();
        let img = read_npy_image(&p, 1, 2).unwrap();
        let expected: Vec<f32> = values.iter().map(|&v| v as f32).collect();
        assert_eq!(img.data, expected);
        // Version 2.0 (a 4-byte header length), double quotes, no trailing comma, Python 2 longs.
        let mut v2 = b"\x93NUMPY\x02\x00".to_vec();
        let dict = "{\"shape\": (2L, 1L, 3L), \"fortran_order\": False, \"descr\": \"<f8\"}\n";
        v2.extend_from_slice(&(dict.len() as u32).to_le_bytes());
        v2.extend_from_slice(dict.as_bytes());
        v2.extend_from_slice(&f8);
        std::fs::write(&p, &v2).unwrap();
        assert_eq!(read_npy_image(&p, 1, 2).unwrap().data, expected);
        // A scalar's and a vector's shapes.
        let h = parse_npy_header(&numpy_file(
            "{'descr': '<f4', 'fortran_order': True, 'shape': (), }",
            &[],
        ))
        .unwrap();
        assert!(h.shape.is_empty() && h.fortran_order);
        let h = parse_npy_header(&numpy_file(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (7,), }",
            &[],
        ))
        .unwrap();
        assert_eq!(h.shape, vec![7]);
    }

    #[test]
    fn hostile_headers_are_refused_in_milliseconds() {
        let start = Instant::now();
        // The header that took the npy crate's parser minutes.
        let braces = numpy_file(&"{".repeat(16), &[]);
        let err = parse_npy_header(&braces).unwrap_err().to_string();
        assert!(err.contains("header"), "{err}");
        let nested = numpy_file(&format!("{}{}", "(".repeat(5000), ")".repeat(5000)), &[]);
        assert!(parse_npy_header(&nested).is_err());
        assert!(
            start.elapsed() < Duration::from_millis(100),
            "{:?}",
            start.elapsed()
        );
        // Declared lengths past the file, or past the limit.
        let mut long = b"\x93NUMPY\x02\x00".to_vec();
        long.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse_npy_header(&long)
            .unwrap_err()
            .to_string()
            .contains("more than"));
        let short = &numpy_file(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), }",
            &[],
        )[..20];
        assert!(parse_npy_header(short)
            .unwrap_err()
            .to_string()
            .contains("truncated"));
        for bad in [
            "{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999999999999,), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (-1,), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), 'shape': (1,)}",
            "{'descr': '<f4', 'fortran_order': Maybe, 'shape': (1,), }",
            "{'descr': '<f4', 'shape': (1,), }",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), } extra",
        ] {
            let err = parse_npy_header(&numpy_file(bad, &[]))
                .unwrap_err()
                .to_string();
            assert!(err.starts_with("header"), "{bad}: {err}");
        }
    }

    #[test]
    fn data_of_another_length_than_the_shape_is_refused() {
        let (_dir, p) = crate::test_files::temp_file("a.npy");
        let dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2, 3), }";
        for n in [0, 47, 49] {
            std::fs::write(&p, numpy_file(dict, &vec![0u8; n])).unwrap();
            let err = read_npy_image(&p, 2, 2).unwrap_err().to_string();
            assert!(err.contains(&format!("{n} bytes of data")), "{err}");
        }
        std::fs::write(&p, numpy_file(dict, &[0u8; 48])).unwrap();
        assert!(read_npy_image(&p, 2, 2).is_ok());
        // A file far larger than the image can be is refused before it is read.
        std::fs::write(&p, numpy_file(dict, &vec![0u8; 1 << 20])).unwrap();
        let err = read_npy_image(&p, 2, 2).unwrap_err().to_string();
        assert!(err.contains("more than"), "{err}");
    }
}
