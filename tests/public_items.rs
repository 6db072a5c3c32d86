//! What the library makes public is chosen, not grown (issue 47): docs/library.md's table of
//! public items per crate must say what the code declares, so that a change which adds a
//! public item also says so in the docs, where a reviewer sees it.
//!
//! The count is the issue's: lines that declare a `pub fn|struct|enum|const|mod|trait|type|
//! static|use`, counted textually in the facade's `src/` and each `crates/*/src` (a struct
//! field named `model` counts as a `mod`, as the issue's pattern has it).
//! `scripts/public_items.py` prints the same counts and who names each item.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

mod source_tree;
use source_tree::rust_files;

/// The keywords after `pub ` that make a line count.
const KEYWORDS: [&str; 9] = [
    "fn", "struct", "enum", "const", "mod", "trait", "type", "static", "use",
];

/// Whether `line` declares a public item by the issue's pattern:
/// `^\s*pub (fn|struct|enum|const|mod|trait|type|static|use)` (no word boundary after it).
fn declares_public_item(line: &str) -> bool {
    line.trim_start()
        .strip_prefix("pub ")
        .is_some_and(|rest| KEYWORDS.iter().any(|keyword| rest.starts_with(keyword)))
}

/// Lines that declare a public item in the `.rs` files under `dir`.
fn count_in(dir: &Path) -> usize {
    let mut files = Vec::new();
    rust_files(dir, &mut files);
    files
        .iter()
        .map(|file| {
            let text = fs::read_to_string(file).expect("a readable source file");
            text.lines()
                .filter(|line| declares_public_item(line))
                .count()
        })
        .sum()
}

/// The count per crate: `nerf` (the facade, `src/`) and each crate under `crates/`.
fn counted(root: &Path) -> BTreeMap<String, usize> {
    let mut counts = BTreeMap::new();
    counts.insert("nerf".to_string(), count_in(&root.join("src")));
    for entry in fs::read_dir(root.join("crates")).expect("the crates folder") {
        let crate_dir = entry.expect("a directory entry").path();
        let name = crate_dir
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        counts.insert(name, count_in(&crate_dir.join("src")));
    }
    counts
}

/// The rows of the table headed `| crate | public items |` in `docs`: the first code-font
/// word of each row's first cell (or `total`) and its number.
fn documented(docs: &str) -> BTreeMap<String, usize> {
    let mut lines = docs
        .lines()
        .skip_while(|line| !line.starts_with("| crate | public items |"));
    assert!(
        lines.next().is_some(),
        "docs/library.md has no `| crate | public items |` table"
    );
    let mut rows = BTreeMap::new();
    for line in lines.skip(1).take_while(|line| line.starts_with('|')) {
        let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
        let name = match cells[0].split('`').nth(1) {
            Some(name) => name.to_string(),
            None => cells[0].trim_matches('*').to_string(),
        };
        let number = cells[1].trim_matches('*').replace(',', "");
        let number = number
            .parse()
            .unwrap_or_else(|_| panic!("not a count: {line}"));
        rows.insert(name, number);
    }
    rows
}

#[test]
fn the_pattern_is_the_issues() {
    assert!(declares_public_item("pub fn render_view("));
    assert!(declares_public_item("    pub struct Rays {"));
    assert!(declares_public_item("pub use nerf_core as core;"));
    // The issue's pattern has no word boundary: a field named `model` counts as a `mod`.
    assert!(declares_public_item("    pub model: Nerf,"));
    assert!(!declares_public_item("pub(crate) fn helper() {}"));
    assert!(!declares_public_item("    pub density: Tensor,"));
    assert!(!declares_public_item("// pub fn in a comment"));
    assert!(!declares_public_item("fn private() {}"));
}

#[test]
fn the_documented_counts_are_the_code_s() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let docs = fs::read_to_string(root.join("docs/library.md")).expect("docs/library.md");
    let mut expected = counted(root);
    expected.insert("total".to_string(), expected.values().sum());
    let table: String = expected
        .iter()
        .map(|(name, n)| format!("\n| `{name}` | {n} |"))
        .collect();
    assert_eq!(
        documented(&docs),
        expected,
        "docs/library.md's public-item table differs from the code; the code's counts:{table}"
    );
}
