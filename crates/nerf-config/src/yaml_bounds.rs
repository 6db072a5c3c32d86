//! Bounds on YAML text before the YAML parser sees it: its size and how deep it nests. The
//! parser's time grows faster than the text with the nesting (measured:
//! docs/reliability.md#yaml-nesting), so a linear scan of the text refuses deep nesting first.
//!
//! The scan counts flow collections (`[`, `{`, outside quoted strings and comments) and block
//! nesting (each deeper indentation, and each `- ` or `? ` that opens an entry on a line),
//! skipping the content of block scalars (`|`, `>`). It over-counts rather than under-counts
//! on odd input; a config nests 4 deep, the limit is `MAX_YAML_DEPTH`.

use anyhow::{bail, Result};

/// Longest config or override text read.
pub const MAX_YAML_BYTES: usize = 1 << 20;
/// Deepest nesting of YAML collections accepted.
pub(crate) const MAX_YAML_DEPTH: usize = 64;

/// An error (one line) when `text` is longer than [`MAX_YAML_BYTES`] or nests deeper than
/// [`MAX_YAML_DEPTH`]; `what` names it ("config", "override value").
pub(crate) fn check_yaml_bounds(text: &str, what: &str) -> Result<()> {
    if text.len() > MAX_YAML_BYTES {
        bail!(
            "{what} is {} bytes, more than the {MAX_YAML_BYTES} read",
            text.len()
        );
    }
    let depth = max_depth(text);
    if depth > MAX_YAML_DEPTH {
        bail!("{what} nests deeper than {MAX_YAML_DEPTH} levels");
    }
    Ok(())
}

/// The scanner's state carried from line to line.
#[derive(Default)]
struct Scan {
    /// Open flow collections.
    flow: usize,
    /// The quote character of a string still open at the end of the last line.
    quote: Option<u8>,
    /// Indentations of the open block levels, increasing.
    indents: Vec<usize>,
    /// Lines indented deeper than this belong to a block scalar.
    block_scalar: Option<usize>,
    /// The deepest nesting seen.
    max: usize,
}

/// The deepest nesting of `text` as the module's scan counts it, stopping early once past
/// the limit.
fn max_depth(text: &str) -> usize {
    let mut s = Scan::default();
    for line in text.lines() {
        s.line(line.as_bytes());
        if s.max > MAX_YAML_DEPTH {
            break;
        }
    }
    s.max
}

impl Scan {
    fn line(&mut self, line: &[u8]) {
        let indent = line.iter().take_while(|&&b| b == b' ').count();
        let body = &line[indent..];
        if let Some(level) = self.block_scalar {
            if body.is_empty() || indent > level {
                return;
            }
            self.block_scalar = None;
        }
        let mut i = 0;
        // Block structure, only outside flow collections and strings.
        if self.flow == 0 && self.quote.is_none() {
            if body.is_empty() || body[0] == b'#' {
                return;
            }
            while self.indents.last().is_some_and(|&top| top >= indent) {
                self.indents.pop();
            }
            self.indents.push(indent);
            let mut entries = 0;
            while i + 1 < body.len() && matches!(body[i], b'-' | b'?') && body[i + 1] == b' ' {
                entries += 1;
                i += 2;
                while body.get(i) == Some(&b' ') {
                    i += 1;
                }
            }
            self.max = self.max.max(self.indents.len() + entries);
        }
        let base = self.indents.len();
        let mut prev = b' ';
        while i < body.len() {
            let b = body[i];
            if let Some(q) = self.quote {
                if b == b'\\' && q == b'"' {
                    i += 1;
                } else if b == q {
                    self.quote = None;
                }
            } else {
                match b {
                    b'#' if prev == b' ' || prev == b'\t' => return,
                    b'\'' | b'"' if matches!(prev, b' ' | b'\t' | b':' | b'[' | b'{' | b',') => {
                        self.quote = Some(b)
                    }
                    b'[' | b'{' => {
                        self.flow += 1;
                        self.max = self.max.max(base + self.flow);
                    }
                    b']' | b'}' => self.flow = self.flow.saturating_sub(1),
                    _ => {}
                }
            }
            prev = b;
            i += 1;
        }
        // `key: |` or `- >-`: the lines indented deeper are text.
        if self.flow == 0 && self.quote.is_none() {
            let end = body
                .iter()
                .rposition(|b| !b.is_ascii_whitespace())
                .map_or(&body[..0], |e| &body[..=e]);
            let word_start = end.iter().rposition(|&b| b == b' ').map_or(0, |p| p + 1);
            let last = &end[word_start..];
            if matches!(last.first(), Some(b'|' | b'>'))
                && last[1..]
                    .iter()
                    .all(|b| matches!(b, b'-' | b'+' | b'1'..=b'9'))
            {
                self.block_scalar = Some(indent);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn the_built_in_configs_pass_and_count_their_depth() {
        for name in ["box", "sphere", "lego", "nerf_lego", "nerf_lego_fast"] {
            let (text, _) = crate::config_text(name).unwrap();
            check_yaml_bounds(&text, "config").unwrap();
            assert!((2..=5).contains(&max_depth(&text)), "{name}");
        }
        assert_eq!(max_depth("a:\n  b:\n    c: [1, [2, {d: 3}]]\n"), 6);
        assert_eq!(max_depth("- - - a\n"), 4);
        // Brackets in strings, comments and block scalars do not count.
        assert_eq!(max_depth("a: '[[[['\nb: \"{{\\\"{{\" # [[[[\n"), 1);
        assert_eq!(max_depth("a: |\n  [[[[\n      [[[[\nb: 1\n"), 1);
    }

    #[test]
    fn deep_or_large_text_is_refused_in_linear_time() {
        let start = Instant::now();
        for text in [
            "[".repeat(100_000),
            format!("a: {}", "{b: ".repeat(100_000)),
            (0..1000)
                .map(|i| format!("{}k:\n", " ".repeat(i)))
                .collect(),
            "- ".repeat(100_000),
        ] {
            let err = check_yaml_bounds(&text, "config").unwrap_err().to_string();
            assert!(
                err.contains("deeper than 64") || err.contains("more than"),
                "{err}"
            );
        }
        assert!(
            start.elapsed() < Duration::from_secs(1),
            "{:?}",
            start.elapsed()
        );
        let err = check_yaml_bounds(&"a".repeat(MAX_YAML_BYTES + 1), "config").unwrap_err();
        assert!(err.to_string().contains("bytes"));
        // A mapping (one level) holding 63 flow levels is at the limit.
        check_yaml_bounds(&format!("a: {}", "[".repeat(63)), "config").unwrap();
        assert!(check_yaml_bounds(&format!("a: {}", "[".repeat(64)), "config").is_err());
    }
}
