//! Measured numbers live in docs/ and in `nerf bench` or `nerf report` output, never in code
//! comments, where they go stale when the code changes (issue 47).
//!
//! The scan is textual: every run of comment lines (`//`, `///`, `//!`) in the workspace's
//! Rust files is joined into one text, and a number that carries a unit of time (seconds,
//! milliseconds, minutes), of quality (decibels, percent) or a speed ratio (a decimal number
//! before `×`, or any number before "× faster") is reported when a word of measuring
//! ("measured", "took", "faster", "against", an arrow, …) stands within a sentence's reach of
//! it. A unit on a setting (a timeout) with no such word nearby passes; so do dimensions
//! (`N×M` matrices) and pointers to the docs ("measured: docs/speed-and-report.md#allocators"),
//! which is where the numbers belong. The test below shows what it flags and what it passes.

use std::fs;
use std::path::Path;

mod source_tree;
use source_tree::rust_files;

/// Folders whose `.rs` files are scanned (the workspace's crates, the facade and binary, the
/// tests and examples).
const SCANNED: [&str; 5] = ["src", "crates", "apps", "tests", "examples"];

/// Units that make a number a time, a score or a share.
const UNITS: [&str; 9] = [
    "s", "ms", "µs", "us", "min", "minutes", "seconds", "dB", "%",
];

/// Words that say a number was measured or compared.
const MEASURING: [&str; 16] = [
    "measured", "took", "takes", "faster", "slower", "against", "→", "->", "scored", "quicker",
    " ran ", "runs in", " cost", "gained", " lost", "saved",
];

/// Characters on each side of a number in which a measuring word counts.
const REACH: usize = 120;

/// The comment text of each run of comment lines in `source`, with the line it starts on.
fn comment_blocks(source: &str) -> Vec<(usize, String)> {
    let mut blocks = Vec::new();
    let mut current: Option<(usize, String)> = None;
    for (i, line) in source.lines().enumerate() {
        let trimmed = line.trim_start();
        if let Some(rest) = trimmed.strip_prefix("//") {
            let text = rest.trim_start_matches(['/', '!']).trim();
            let block = current.get_or_insert_with(|| (i + 1, String::new()));
            block.1.push(' ');
            block.1.push_str(text);
        } else if let Some(block) = current.take() {
            blocks.push(block);
        }
    }
    blocks.extend(current);
    blocks
}

/// Byte ranges of the numbers in `text` that carry a measured unit: digits (with an optional
/// decimal part and an optional range `a–b` or `a-b`), then optional spaces, then a unit of
/// [`UNITS`] that ends the word, or `×` after a decimal number or before "faster"/"slower".
fn measured_quantities(text: &str) -> Vec<(usize, usize)> {
    let chars: Vec<(usize, char)> = text.char_indices().collect();
    let mut found = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let (start, c) = chars[i];
        let starts_number = c.is_ascii_digit()
            && (i == 0 || {
                let before = chars[i - 1].1;
                !(before.is_alphanumeric() || before == '.' || before == '_' || before == '^')
            });
        if !starts_number {
            i += 1;
            continue;
        }
        let mut j = i;
        let mut decimal = false;
        let read_number = |j: &mut usize, decimal: &mut bool| {
            while *j < chars.len() && chars[*j].1.is_ascii_digit() {
                *j += 1;
            }
            if *j + 1 < chars.len() && chars[*j].1 == '.' && chars[*j + 1].1.is_ascii_digit() {
                *decimal = true;
                *j += 1;
                while *j < chars.len() && chars[*j].1.is_ascii_digit() {
                    *j += 1;
                }
            }
        };
        read_number(&mut j, &mut decimal);
        // A range: `0.3–0.4 s`, `3-5 min`.
        if j + 1 < chars.len() && matches!(chars[j].1, '-' | '–') && chars[j + 1].1.is_ascii_digit()
        {
            j += 1;
            read_number(&mut j, &mut decimal);
        }
        let mut k = j;
        while k < chars.len() && chars[k].1 == ' ' {
            k += 1;
        }
        let rest_at = chars.get(k).map_or(text.len(), |&(at, _)| at);
        let rest = &text[rest_at..];
        let unit_ends_word = |unit: &str| {
            rest.starts_with(unit)
                && !rest[unit.len()..]
                    .chars()
                    .next()
                    .is_some_and(|n| n.is_alphanumeric() || n == '²' || n == '_')
        };
        let unit = UNITS.iter().find(|u| unit_ends_word(u)).map(|u| u.len());
        let ratio = rest.strip_prefix('×').and_then(|after| {
            let after = after.trim_start();
            (decimal || after.starts_with("faster") || after.starts_with("slower"))
                .then_some('×'.len_utf8())
        });
        if let Some(len) = unit.or(ratio) {
            found.push((start, rest_at + len));
        }
        i = j.max(i + 1);
    }
    found
}

/// The measured numbers of one comment text: each quantity with a measuring word in reach.
fn measured_statements(text: &str) -> Vec<String> {
    measured_quantities(text)
        .into_iter()
        .filter_map(|(start, end)| {
            let from = floor_char_boundary(text, start.saturating_sub(REACH));
            let to = floor_char_boundary(text, (end + REACH).min(text.len()));
            let around = text[from..to].to_lowercase();
            MEASURING
                .iter()
                .any(|w| around.contains(w))
                .then(|| text[start..end].to_string())
        })
        .collect()
}

/// The largest char boundary of `text` at or below `at`.
fn floor_char_boundary(text: &str, mut at: usize) -> usize {
    while !text.is_char_boundary(at) {
        at -= 1;
    }
    at
}

#[test]
fn no_comment_states_a_measured_time_or_ratio() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in SCANNED {
        rust_files(&root.join(dir), &mut files);
    }
    assert!(files.len() > 100, "found only {} Rust files", files.len());
    let mut problems = Vec::new();
    for file in files {
        let source = fs::read_to_string(&file).unwrap();
        for (line, text) in comment_blocks(&source) {
            for number in measured_statements(&text) {
                let shown = file.strip_prefix(root).unwrap_or(&file).display();
                problems.push(format!("{shown}:{line}: `{number}`"));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "comments state measured numbers; move them to docs/ and point there:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_scan_finds_measured_numbers_and_passes_settings() {
    let flagged = |text: &str| measured_statements(text);
    // Measurements: times compared, ratios, scores, shares.
    assert_eq!(flagged("took 0.39 s against 0.32 s"), ["0.39 s", "0.32 s"]);
    assert_eq!(
        flagged("a frame 0.329-0.333 → 0.300-0.308 s"),
        ["0.300-0.308 s"]
    );
    assert_eq!(flagged("the gemm ran 1.6× the AVX2 rate"), ["1.6×"]);
    assert_eq!(flagged("about 2× faster than before"), ["2×"]);
    assert_eq!(flagged("was 10% faster than in four chunks"), ["10%"]);
    assert_eq!(flagged("scored 27.2 dB on the bird"), ["27.2 dB"]);
    assert_eq!(flagged("in 3 to 5 min it measured a loss"), ["5 min"]);
    // Settings, dimensions, exponents and pointers to the docs pass.
    assert!(flagged("the header timeout (10 s)").is_empty());
    assert!(flagged("a 4×4 matrix against the 3×3 block").is_empty());
    assert!(flagged("capped at 120 dB so that the log stays finite").is_empty());
    assert!(flagged("2^16 samples, faster (measured: docs/speed.md#allocators)").is_empty());
    assert!(flagged("x1s and 3ms_budget are names, took nothing").is_empty());
}

#[test]
fn comment_blocks_join_consecutive_comment_lines() {
    let source = "fn a() {}\n/// took 1.5\n/// s against 2 s\nfn b() {}\n// one\n";
    let blocks = comment_blocks(source);
    assert_eq!(blocks.len(), 2);
    assert_eq!(blocks[0].0, 2);
    assert_eq!(measured_statements(&blocks[0].1), ["1.5 s", "2 s"]);
    assert_eq!(blocks[1], (5, " one".to_string()));
}
