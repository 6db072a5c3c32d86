//! Docs that stay true (issue 32): what README.md, docs/*.md and the doc comments (`//!`,
//! `///`) of src/, tests/ and examples/ name must exist in the tree.
//!
//! * Every path under `src/` (or `tests/`, `examples/`, `crates/`, `apps/`) names a file or folder
//!   that exists.
//! * Every file or folder listed in a row of a layout table (`| folder/ | … |`, as in
//!   docs/library.md) exists in that row's folder.
//! * Every item path that starts with `crate`, `nerf` or a workspace crate's name
//!   (`nerf_core`) resolves. Resolution is textual: the
//!   longest prefix that is a module (a file `a/b.rs` or `a/b/mod.rs`, a `#[path]` module or an
//!   inline `mod`), then the rest defined in that module's file (an item, a method, a variant,
//!   a field) or re-exported by a `pub use` there, which is followed. Inside the command's
//!   files (apps/nerf/src/) `crate` is the command's tree, inside a workspace crate's files
//!   (crates/<name>/) that crate's, elsewhere the `nerf` facade's; `nerf` is always the
//!   facade, and a re-export of a workspace crate is followed into it.
//!
//! Paths that end in `…` or use `*` stand for many and are skipped, as are paths to other
//! projects' sources (COLMAP's `.h` files). Every missing reference is reported at once, with
//! its file and line.

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

/// The top folders whose paths are checked when a document names them.
const CHECKED_PATH_ROOTS: [&str; 5] = ["src/", "tests/", "examples/", "crates/", "apps/"];

/// The folder of the workspace's library crates: `crates/<name>/src/lib.rs` is the crate
/// `<name>` (with `-` written `_` in paths).
const CRATES: &str = "crates";

/// The folder of the workspace's applications (the `nerf` command's package, apps/nerf).
const APPS: &str = "apps";

/// The `nerf` command's sources: `crate` in them is the command's tree, rooted at `main.rs`.
const COMMAND_SOURCES: &str = "apps/nerf/src";

/// Extensions of other projects' sources: a `src/…` path ending in one names a file of theirs.
const FOREIGN_EXTENSIONS: [&str; 7] = [".h", ".hpp", ".c", ".cc", ".cpp", ".cu", ".py"];

/// The keywords that introduce a named item.
const ITEM_KEYWORDS: [&str; 10] = [
    "fn",
    "struct",
    "enum",
    "trait",
    "type",
    "const",
    "static",
    "mod",
    "union",
    "macro_rules!",
];

/// Re-exports are followed at most this deep (a cycle would otherwise never end).
const MAX_REEXPORT_DEPTH: usize = 8;

/// One line of documentation: where it is, and its text (a doc comment without its marker).
struct DocLine {
    file: PathBuf,
    line: usize,
    text: String,
}

impl DocLine {
    fn place(&self) -> String {
        format!("{}:{}", self.file.display(), self.line)
    }
}

/// Files read once and kept: resolution reads the same module files many times.
#[derive(Default)]
struct Sources {
    texts: HashMap<PathBuf, String>,
}

impl Sources {
    fn read(&mut self, file: &Path) -> &str {
        self.texts
            .entry(file.to_path_buf())
            .or_insert_with(|| fs::read_to_string(file).unwrap_or_default())
    }
}

/// One module: the file its text is in, where its child module files live, and its path.
#[derive(Clone)]
struct Module {
    file: PathBuf,
    children_dir: PathBuf,
    path: Vec<String>,
}

#[test]
fn every_path_and_item_the_docs_name_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut sources = Sources::default();
    let mut missing = Vec::new();
    for doc in documentation_lines(root) {
        for path in tree_paths(&doc.text) {
            if !root.join(&path).exists() {
                missing.push(format!("{}: `{path}` does not exist", doc.place()));
            }
        }
        for name in layout_table_entries(&doc.text) {
            if !root.join(&name).exists() {
                missing.push(format!("{}: `{name}` does not exist", doc.place()));
            }
        }
        for item in item_paths(&doc.text) {
            let crate_root = crate_root_for(root, &doc.file, &item[0]);
            if let Err(why) = resolve(&crate_root, &item[1..], &mut sources, 0) {
                let written = item.join("::");
                let why = why.replace(&format!("{}/", root.display()), "");
                missing.push(format!("{}: `{written}`: {why}", doc.place()));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "{} references in the docs name nothing in the tree:\n{}",
        missing.len(),
        missing.join("\n")
    );
}

#[test]
fn paths_are_read_as_written_in_prose() {
    let found = |text: &str| tree_paths(text);
    assert_eq!(found("held in `src/io/output.rs`."), ["src/io/output.rs"]);
    assert_eq!(
        found("the folder src/io/dataset/, one file a format"),
        ["src/io/dataset/"]
    );
    assert!(found("all of `src/…` and src/kernels/*.rs").is_empty());
    assert!(found("COLMAP's `src/colmap/sensor/models.h`").is_empty());
    assert!(found("https://github.com/colmap/colmap/blob/main/src/colmap/x.cc").is_empty());
    let row = "| `src/io/` | PLY (`ply.rs`), `apps/nerf/tests/output.rs`, colmap (`colmap/`), `look_at` |";
    assert_eq!(
        layout_table_entries(row),
        ["src/io/ply.rs", "src/io/colmap/"]
    );
}

/// Resolves the one item path in `written`, as if written in `file`.
fn check(file: &str, written: &str) -> Result<(), String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let item = item_paths(written).pop().expect("one item path");
    let crate_root = crate_root_for(root, Path::new(file), &item[0]);
    resolve(&crate_root, &item[1..], &mut Sources::default(), 0)
}

#[test]
fn resolution_finds_modules_items_members_and_reexports() {
    let found = [
        (
            "src/lib.rs",
            "`crate::render::field::FieldFastPaths::render_fused`",
        ), // a trait's method
        ("src/lib.rs", "[`crate::core::sdf::Sdf::Box`]"), // a variant
        ("src/lib.rs", "crate::core::camera::colmap::tests"), // a #[path] module in a re-exported crate
        ("README.md", "nerf_core::rays::Rays"),               // a workspace crate by name
        (
            "crates/nerf-core/src/rays.rs",
            "crate::volume::transmittance",
        ), // inside that crate
        ("src/lib.rs", "crate::io::dataset::Split"),          // a glob re-export
        (
            "crates/nerf-core/src/rays.rs",
            "crate::camera::ColmapCamera::project",
        ), // an entry of a list of kinds that its macro re-exports
        ("README.md", "`nerf::VolumeRenderer::render`"),      // lib.rs's re-export
        ("README.md", "nerf::config::DataConfig::dataset_image_size"), // a relative re-export
        ("README.md", "nerf::candle_core::Tensor"),           // another crate's item
        (
            "apps/nerf/src/bench/row.rs",
            "crate::bench::hash_grid_rows::NgpFlops",
        ), // the binary's tree
    ];
    for (file, written) in found {
        assert_eq!(check(file, written), Ok(()), "{written} in {file}");
    }
}

#[test]
fn resolution_reports_what_is_not_there() {
    let not_found = [
        ("src/lib.rs", "crate::render::field::Field::no_such_method"),
        ("src/lib.rs", "crate::core::no_such_module::Thing"),
        ("crates/nerf-core/src/rays.rs", "crate::io::dataset::Split"), // the facade's, not the crate's
        ("src/lib.rs", "crate::bench::hash_grid_rows::NgpFlops"), // the binary's, not the library's
        ("README.md", "nerf::NoSuchReexport"),
        ("README.md", "nerf::io::dataset::NoSuchItem"),
        ("crates/nerf-core/src/rays.rs", "crate::camera::NoSuchKind"), // not in the list
    ];
    for (file, written) in not_found {
        assert!(check(file, written).is_err(), "{written} in {file}");
    }
}

// ---- Where documentation is ----

/// Every line of README.md and docs/*.md (but the added lines of a ```diff block, which name
/// what a change would add), and every doc-comment line of the Rust files under
/// src/, tests/, examples/ and crates/. File names are relative to the workspace root.
fn documentation_lines(root: &Path) -> Vec<DocLine> {
    let mut files = vec![PathBuf::from("README.md")];
    files.extend(files_under(root, Path::new("docs"), "md"));
    for folder in ["src", "tests", "examples", CRATES, APPS] {
        files.extend(files_under(root, Path::new(folder), "rs"));
    }
    let mut lines = Vec::new();
    for file in files {
        let text = fs::read_to_string(root.join(&file)).expect("a listed file reads");
        let markdown = file.extension().is_some_and(|e| e == "md");
        let mut in_diff = false;
        for (index, line) in text.lines().enumerate() {
            if markdown && line.starts_with("```") {
                in_diff = !in_diff && line.trim_start_matches('`').trim() == "diff";
            }
            let text = if markdown {
                // A worked diff is code, whose paths are relative to its own file; only its
                // `--- a/…` lines, which name a file that the diff changes, are checked.
                (!in_diff || line.starts_with("--- a/"))
                    .then(|| line.strip_prefix("--- a/").unwrap_or(line))
            } else {
                doc_comment_text(line)
            };
            if let Some(text) = text {
                let (file, line, text) = (file.clone(), index + 1, text.to_string());
                lines.push(DocLine { file, line, text });
            }
        }
    }
    lines
}

/// The files with this extension under `folder` (relative to `root`), at any depth, sorted.
fn files_under(root: &Path, folder: &Path, extension: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let Ok(entries) = fs::read_dir(root.join(folder)) else {
        return found;
    };
    for entry in entries.flatten() {
        let relative = folder.join(entry.file_name());
        if entry.file_type().is_ok_and(|t| t.is_dir()) {
            found.extend(files_under(root, &relative, extension));
        } else if relative.extension().is_some_and(|e| e == extension) {
            found.push(relative);
        }
    }
    found.sort();
    found
}

/// The text of a `//!` or `///` comment line (not `////`), or `None` for any other line.
fn doc_comment_text(line: &str) -> Option<&str> {
    let trimmed = line.trim_start();
    if trimmed.starts_with("////") {
        return None;
    }
    trimmed
        .strip_prefix("//!")
        .or_else(|| trimmed.strip_prefix("///"))
}

// ---- What documentation names ----

fn is_ident_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The `src/…`, `tests/…` and `examples/…` paths a line names. A path stops at the first
/// character that cannot be in one; a full stop that ends a sentence is not part of it.
fn tree_paths(text: &str) -> Vec<String> {
    let mut paths = Vec::new();
    for prefix in CHECKED_PATH_ROOTS {
        for (at, _) in text.match_indices(prefix) {
            let before = text[..at].chars().next_back();
            if before.is_some_and(|c| is_ident_char(c) || c == '/' || c == '.' || c == '-') {
                continue; // part of a longer path or a URL: another tree's `src/`
            }
            let rest = &text[at..];
            let end = rest
                .find(|c: char| !(is_ident_char(c) || "./-".contains(c)))
                .unwrap_or(rest.len());
            let path = rest[..end].trim_end_matches('.');
            let after = &rest[path.len()..];
            let many = after.starts_with('…') || after.starts_with('*') || after.starts_with('{');
            let foreign = FOREIGN_EXTENSIONS.iter().any(|e| path.ends_with(e));
            if !many && !foreign {
                paths.push(path.to_string());
            }
        }
    }
    paths
}

/// The files and folders a layout-table row lists (`| `src/io/` | … (`ply.rs`) … |`), each
/// joined to the row's folder. Names with a `/` inside are paths of their own, not entries.
fn layout_table_entries(text: &str) -> Vec<String> {
    let Some(row) = text.strip_prefix("| `") else {
        return Vec::new();
    };
    let Some((folder, rest)) = row.split_once('`') else {
        return Vec::new();
    };
    if !folder.ends_with('/') || folder.contains(' ') {
        return Vec::new();
    }
    let mut entries = Vec::new();
    for (index, quoted) in rest.split('`').enumerate() {
        let inside = index % 2 == 1;
        let entry = quoted.trim_end_matches('/');
        let simple = !entry.is_empty() && entry.chars().all(|c| is_ident_char(c) || c == '.');
        if inside && simple && (quoted.ends_with(".rs") || quoted.ends_with('/')) {
            entries.push(format!("{folder}{quoted}"));
        }
    }
    entries
}

/// The item paths a line names that start with `crate` or `nerf`, as segments
/// (`["crate", "render", "field", "Field"]`). A group in braces on the same line
/// (`nerf::{Field, render_view}`) gives one path a member; a path that ends in `…` or `*`,
/// or whose group goes on past the line or nests, is skipped.
fn item_paths(text: &str) -> Vec<Vec<String>> {
    let mut paths = Vec::new();
    let mut starts = vec!["crate::".to_string(), "nerf::".to_string()];
    starts.extend(
        workspace_crate_names()
            .iter()
            .map(|name| format!("{name}::")),
    );
    for start in &starts {
        for (at, _) in text.match_indices(start.as_str()) {
            let before = text[..at].chars().next_back();
            if before.is_some_and(|c| is_ident_char(c) || c == ':' || c == '$') {
                continue;
            }
            let (segments, after) = leading_path(&text[at..]);
            if let Some(group) = after.strip_prefix("::{") {
                paths.extend(group_members(group).into_iter().map(|member| {
                    let mut path = segments.clone();
                    path.extend(member);
                    path
                }));
            } else if segments.len() > 1 && !stands_for_many(after) {
                paths.push(segments);
            }
        }
    }
    paths
}

/// Whether the text after a path makes it stand for many (`a::…`, `a…`, `a::*`).
fn stands_for_many(after: &str) -> bool {
    ["::…", "…", "::*"]
        .iter()
        .any(|more| after.starts_with(more))
}

/// The identifiers of `a::b::c` at the start of `text`, and the text after them.
fn leading_path(text: &str) -> (Vec<String>, &str) {
    let mut segments = Vec::new();
    let mut rest = text;
    loop {
        let end = rest.find(|c: char| !is_ident_char(c)).unwrap_or(rest.len());
        if end == 0 {
            break;
        }
        segments.push(rest[..end].to_string());
        rest = &rest[end..];
        match rest.strip_prefix("::") {
            Some(next) if next.starts_with(is_ident_char) => rest = next,
            _ => break,
        }
    }
    (segments, rest)
}

/// The members of a brace group whose text starts just after its `{`, each as segments;
/// none where the group does not close on this line or holds another group.
fn group_members(group: &str) -> Vec<Vec<String>> {
    let Some((inside, _)) = group.split_once('}') else {
        return Vec::new();
    };
    if inside.contains('{') || inside.contains('*') {
        return Vec::new();
    }
    inside
        .split(',')
        .map(|member| member.split(" as ").next().unwrap_or("").trim())
        .filter(|member| !member.is_empty() && *member != "self")
        .map(|member| leading_path(member).0)
        .collect()
}

// ---- Resolving an item path ----

/// The module `crate`, `nerf` or a workspace crate's name stands for in `file`: for `crate`,
/// the command's tree inside apps/nerf/src/, a workspace crate's inside crates/<name>/, the
/// facade's everywhere else.
fn crate_root_for(root: &Path, file: &Path, start: &str) -> Module {
    if let Some(krate) = workspace_crate(start) {
        return krate;
    }
    let binary = root.join(COMMAND_SOURCES);
    if start == "crate" && file.starts_with(COMMAND_SOURCES) {
        return Module {
            file: binary.join("main.rs"),
            children_dir: binary,
            path: Vec::new(),
        };
    }
    if start == "crate" && file.starts_with(CRATES) {
        if let Some(name) = file.iter().nth(1).and_then(|n| n.to_str()) {
            if let Some(krate) = workspace_crate(&name.replace('-', "_")) {
                return krate;
            }
        }
    }
    Module {
        file: root.join("src/lib.rs"),
        children_dir: root.join("src"),
        path: Vec::new(),
    }
}

/// The names of the workspace's library crates as paths write them (`nerf_core`), read once.
fn workspace_crate_names() -> &'static [String] {
    static NAMES: std::sync::OnceLock<Vec<String>> = std::sync::OnceLock::new();
    NAMES.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join(CRATES);
        let Ok(entries) = fs::read_dir(root) else {
            return Vec::new();
        };
        let mut names: Vec<String> = entries
            .flatten()
            .filter(|e| e.path().join("src/lib.rs").is_file())
            .filter_map(|e| e.file_name().to_str().map(|n| n.replace('-', "_")))
            .collect();
        names.sort();
        names
    })
}

/// The root module of the workspace crate a path calls `name` (`nerf_core`), if there is one.
fn workspace_crate(name: &str) -> Option<Module> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(CRATES)
        .join(name.replace('_', "-"))
        .join("src");
    let file = dir.join("lib.rs");
    file.is_file().then(|| Module {
        file,
        children_dir: dir,
        path: Vec::new(),
    })
}

/// Checks that `segments` (after `crate`) name something in the tree of `crate_root`, or
/// says what is missing.
fn resolve(
    crate_root: &Module,
    segments: &[String],
    sources: &mut Sources,
    depth: usize,
) -> Result<(), String> {
    if depth > MAX_REEXPORT_DEPTH {
        return Err("re-exports go round in a loop".to_string());
    }
    let mut module = crate_root.clone();
    let mut rest = segments;
    while let Some((name, tail)) = rest.split_first() {
        match child_module(&module, name, sources) {
            Some(child) => (module, rest) = (child, tail),
            None => break,
        }
    }
    let Some((item, members)) = rest.split_first() else {
        return Ok(());
    };
    let text = sources.read(&module.file).to_string();
    if defines_item(&text, item) {
        return match members.iter().find(|m| !defines_member(&text, m)) {
            None => Ok(()),
            Some(member) => Err(format!("no `{member}` in {}", module.file.display())),
        };
    }
    for target in reexport_targets(&text, item) {
        let krate = target.first().and_then(|first| workspace_crate(first));
        if let Some(krate) = krate {
            let path = [&target[1..], members].concat();
            if resolve(&krate, &path, sources, depth + 1).is_ok() {
                return Ok(());
            }
            continue;
        }
        let Some(mut path) = absolute_use_path(&module, &target, sources) else {
            return Ok(()); // re-exported from another crate: nothing here to check
        };
        path.extend(members.iter().cloned());
        if resolve(crate_root, &path, sources, depth + 1).is_ok() {
            return Ok(());
        }
    }
    Err(format!("no `{item}` in {}", module.file.display()))
}

/// The child module `name` of `module`: a `#[path]` file, `name.rs`, `name/mod.rs`, or an
/// inline `mod name { … }` (whose text is its parent's file).
fn child_module(module: &Module, name: &str, sources: &mut Sources) -> Option<Module> {
    let mut path = module.path.clone();
    path.push(name.to_string());
    let text = sources.read(&module.file).to_string();
    if let Some(file) = path_attribute(&text, name) {
        let file = module.file.parent()?.join(file);
        let children_dir = file.parent()?.to_path_buf();
        return Some(Module {
            file,
            children_dir,
            path,
        });
    }
    // `name.rs` beside its parent, or `name/mod.rs`; either way its children are in `name/`.
    let children_dir = module.children_dir.join(name);
    let files = [
        module.children_dir.join(format!("{name}.rs")),
        children_dir.join("mod.rs"),
    ];
    if let Some(file) = files.into_iter().find(|f| f.is_file()) {
        return Some(Module {
            file,
            children_dir,
            path,
        });
    }
    if text.contains(&format!("mod {name} {{")) {
        let children_dir = module.children_dir.join(name);
        return Some(Module {
            file: module.file.clone(),
            children_dir,
            path,
        });
    }
    None
}

/// The file of `#[path = "…"] mod name;` in `text`, if it declares one.
fn path_attribute(text: &str, name: &str) -> Option<String> {
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    lines.windows(2).find_map(|pair| {
        let declares = pair[1]
            .trim_start_matches("pub ")
            .starts_with(&format!("mod {name};"));
        let file = pair[0].strip_prefix("#[path = \"")?.strip_suffix("\"]")?;
        declares.then(|| file.to_string())
    })
}

/// Whether `text` defines an item `name`: `fn name`, `struct name`, … `macro_rules! name`.
fn defines_item(text: &str, name: &str) -> bool {
    text.match_indices(name).any(|(at, _)| {
        let after = text[at + name.len()..].chars().next();
        let word_ends = !after.is_some_and(is_ident_char);
        let before = text[..at].trim_end();
        let keyword = ITEM_KEYWORDS.iter().any(|k| {
            before.ends_with(k)
                && !before[..before.len() - k.len()]
                    .chars()
                    .next_back()
                    .is_some_and(is_ident_char)
        });
        word_ends && keyword
    })
}

/// Whether `text` defines a member `name` of an item: a method or associated item (found as
/// an item), or an enum variant or struct field (a line that starts with the name followed
/// by `(`, `{`, `,`, `:`, `=`, or nothing).
fn defines_member(text: &str, name: &str) -> bool {
    defines_item(text, name)
        || text.lines().any(|line| {
            let line = line.trim_start();
            let line = line.strip_prefix("pub(crate) ").unwrap_or(line);
            let line = line.strip_prefix("pub ").unwrap_or(line);
            let Some(after) = line.strip_prefix(name) else {
                return false;
            };
            let after = after.trim_start();
            after.is_empty()
                || (after.starts_with(['(', '{', ',', '=']))
                || (after.starts_with(':') && !after.starts_with("::"))
        })
}

/// The paths `text` re-exports under the name `name` (`pub use a::b::name;`,
/// `pub use a::{b::c as name};`), and every glob it re-exports (`pub use a::*` gives
/// `a::name`), as written in the `use`.
fn reexport_targets(text: &str, name: &str) -> Vec<Vec<String>> {
    let mut targets = Vec::new();
    for tree in pub_use_trees(text) {
        for path in expand_use_tree(&tree) {
            let (target, exported) = match path.split_once(" as ") {
                Some((target, alias)) => (target.to_string(), alias.to_string()),
                None => (
                    path.clone(),
                    path.rsplit("::").next().unwrap_or("").to_string(),
                ),
            };
            let target = target.strip_suffix("::self").unwrap_or(&target).to_string();
            if exported == name {
                targets.push(target.split("::").map(String::from).collect());
            } else if let Some(glob) = target.strip_suffix("::*") {
                let mut path: Vec<String> = glob.split("::").map(String::from).collect();
                path.push(name.to_string());
                targets.push(path);
            }
        }
    }
    targets.extend(kind_list_targets(text, name));
    targets
}

/// The entries of a list of kinds whose macro re-exports each (`pub use $module::$kind;` in
/// its body, one `Variant => module::Kind,` line an entry, as `camera_kinds!` and
/// `lens_models!` write them) that are called `name`: `module::name`.
fn kind_list_targets(text: &str, name: &str) -> Vec<Vec<String>> {
    if !text.contains("pub use $module::$") {
        return Vec::new();
    }
    text.lines()
        .filter_map(|line| {
            let (_, path) = line.trim().strip_suffix(',')?.split_once(" => ")?;
            let (module, kind) = path.split_once("::")?;
            (kind == name).then(|| vec![module.to_string(), kind.to_string()])
        })
        .collect()
}

/// The use trees of the `pub use …;` statements in `text` (a statement may span lines), each
/// on one line with single spaces (`a::{B,c::D as E}`).
fn pub_use_trees(text: &str) -> Vec<String> {
    let mut trees = Vec::new();
    let mut unfinished: Option<String> = None;
    for line in text.lines().map(str::trim) {
        let start = line
            .strip_prefix("pub use ")
            .or_else(|| line.strip_prefix("pub(crate) use "));
        let tree = match (unfinished.take(), start) {
            (Some(so_far), _) => format!("{so_far} {line}"),
            (None, Some(start)) => start.to_string(),
            (None, None) => continue,
        };
        match tree.split_once(';') {
            Some((tree, _)) => trees.push(tidy_use_tree(tree)),
            None => unfinished = Some(tree),
        }
    }
    trees
}

/// A use tree with no spaces but those around `as`.
fn tidy_use_tree(tree: &str) -> String {
    let spaced = tree.split_whitespace().collect::<Vec<_>>().join(" ");
    spaced
        .replace("{ ", "{")
        .replace(" }", "}")
        .replace(", ", ",")
        .replace(" ,", ",")
}

/// The paths of a use tree: `a::{B, c::{D, E}}` gives `a::B`, `a::c::D`, `a::c::E`.
fn expand_use_tree(tree: &str) -> Vec<String> {
    let Some(open) = tree.find('{') else {
        return vec![tree.trim_end_matches(',').to_string()];
    };
    let (prefix, group) = (&tree[..open], &tree[open + 1..tree.len() - 1]);
    split_top_level(group)
        .into_iter()
        .flat_map(expand_use_tree)
        .map(|path| format!("{prefix}{path}"))
        .collect()
}

/// `group` split at its commas outside braces.
fn split_top_level(group: &str) -> Vec<&str> {
    let (mut parts, mut depth, mut start) = (Vec::new(), 0, 0);
    for (at, c) in group.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&group[start..at]);
                start = at + 1;
            }
            _ => {}
        }
    }
    parts.push(&group[start..]);
    parts.into_iter().filter(|part| !part.is_empty()).collect()
}

/// A use path (as written in `module`) from the crate root, or `None` where it leaves the
/// crate (another crate's name).
fn absolute_use_path(
    module: &Module,
    path: &[String],
    sources: &mut Sources,
) -> Option<Vec<String>> {
    let (first, rest) = path.split_first()?;
    match first.as_str() {
        "crate" => Some(rest.to_vec()),
        "self" => Some([module.path.clone(), rest.to_vec()].concat()),
        "super" => {
            let mut base = module.path.clone();
            base.pop();
            let mut rest = rest;
            while let Some(("super", further)) = rest.split_first().map(|(s, r)| (s.as_str(), r)) {
                base.pop();
                rest = further;
            }
            Some([base, rest.to_vec()].concat())
        }
        _ if child_module(module, first, sources).is_some() => {
            Some([module.path.clone(), path.to_vec()].concat())
        }
        _ => None,
    }
}
