//! Every `nerf` command the documentation shows parses: README.md and docs/*.md are scanned
//! for fenced shell blocks (```sh, ```bash, ```shell or a bare ```), and each line there that
//! starts with `nerf ` or `cargo run --release -- ` (after joining `\` continuations) is given
//! to [`Cli::try_parse_from`], which checks it against the real argument definitions without
//! running anything.
//!
//! A line is split as a shell would split it in the simple cases the docs use: words at
//! whitespace, '…' and "…" quoting, and the command ends at a word that starts a comment
//! (`#`) or at `|`, `>`, `&&` or `;`. Usage notation is expanded rather than skipped: an
//! optional group (`[--json]`, `[--save-images DIR]`, a run of words from one starting `[-` to
//! one ending `]`) is checked both left out and put in, and a placeholder (`<name>`, or an
//! all-capitals word such as `DIR` or `N`) stands for the value `1`, which every option that
//! takes a count, a path or a name accepts.
use std::path::{Path, PathBuf};

use crate::cli::Cli;
use clap::Parser;

/// A command found in the docs: where it is and its words after `nerf`.
#[derive(Debug)]
struct DocCommand {
    file: PathBuf,
    line: usize,
    text: String,
}

/// The fenced blocks' languages whose lines are shell commands.
fn is_shell_fence(info: &str) -> bool {
    matches!(info.trim(), "" | "sh" | "bash" | "shell" | "console")
}

/// The `nerf` commands of the Markdown `text` (the file `file`): each with the line it starts
/// on, continuations joined, the `nerf ` or `cargo run --release -- ` prefix removed.
fn commands_in(file: &Path, text: &str) -> Vec<DocCommand> {
    let mut found = Vec::new();
    let mut in_shell_block = None::<bool>;
    let mut pending: Option<(usize, String)> = None;
    for (i, raw) in text.lines().enumerate() {
        let trimmed = raw.trim_start();
        if let Some(info) = trimmed.strip_prefix("```") {
            in_shell_block = match in_shell_block {
                None => Some(is_shell_fence(info)),
                Some(_) => None,
            };
            pending = None;
            continue;
        }
        if in_shell_block != Some(true) {
            continue;
        }
        let (start, mut line) = match pending.take() {
            Some((start, head)) => (start, format!("{head} {}", trimmed.trim())),
            None => (i + 1, trimmed.trim().to_string()),
        };
        if let Some(head) = line.strip_suffix('\\') {
            line = head.trim_end().to_string();
            pending = Some((start, line));
            continue;
        }
        if let Some(args) = nerf_arguments(&line) {
            found.push(DocCommand {
                file: file.to_path_buf(),
                line: start,
                text: args.to_string(),
            });
        }
    }
    found
}

/// The arguments after `nerf` of a shell line that runs it (`nerf …`, `cargo run --release
/// -- …`, or `cargo run --release --features F -- …`).
fn nerf_arguments(line: &str) -> Option<&str> {
    if let Some(rest) = line.strip_prefix("nerf ") {
        return Some(rest);
    }
    let rest = line.strip_prefix("cargo run --release ")?;
    let rest = match rest.strip_prefix("--features ") {
        Some(features) => features.split_once(' ')?.1,
        None => rest,
    };
    rest.strip_prefix("-- ")
}

/// The words of a command as a shell splits them (whitespace, '…' and "…" quotes), up to a
/// comment, pipe, redirection, `&&` or `;`.
fn shell_words(command: &str) -> Vec<String> {
    let chars: Vec<char> = command.chars().collect();
    let mut words = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut quote = None::<char>;
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        i += 1;
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                in_word = true;
            }
            (None, c) if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            (None, '#') if !in_word => break,
            // `<name>` is usage notation for a value, not a redirection.
            (None, '<') if !in_word && chars[i..].contains(&'>') => {
                let end = i + chars[i..].iter().position(|&c| c == '>').unwrap_or(0) + 1;
                word.push(c);
                word.extend(&chars[i..end]);
                i = end;
                in_word = true;
            }
            (None, '|' | '>' | ';') => break,
            (None, '&') if chars.get(i) == Some(&'&') => break,
            (None, c) => {
                word.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// A placeholder of usage notation: `<name>` or an all-capitals word (`DIR`, `N`).
fn is_placeholder(word: &str) -> bool {
    (word.starts_with('<') && word.ends_with('>'))
        || (word.chars().next().is_some_and(|c| c.is_ascii_uppercase())
            && word
                .chars()
                .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_'))
}

/// The argument lists a command in usage notation stands for: its optional groups (`[-…]`)
/// all left out, and all put in; placeholders replaced by `1`.
fn expansions(words: &[String]) -> Vec<Vec<String>> {
    let mut without = Vec::new();
    let mut with = Vec::new();
    let mut in_group = false;
    for w in words {
        let mut w = w.as_str();
        let opens = !in_group && w.starts_with("[-");
        if opens {
            in_group = true;
            w = &w[1..];
        }
        let closes = in_group && w.ends_with(']');
        if closes {
            w = &w[..w.len() - 1];
        }
        let value = if is_placeholder(w) { "1" } else { w };
        if !in_group {
            without.push(value.to_string());
        }
        with.push(value.to_string());
        if closes {
            in_group = false;
        }
    }
    if with == without {
        vec![with]
    } else {
        vec![without, with]
    }
}

/// The repository's root, two folders above this package's (`apps/nerf`).
const REPO_ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");

/// README.md and every docs/*.md, sorted.
fn doc_files() -> Vec<PathBuf> {
    let root = Path::new(REPO_ROOT);
    let mut files = vec![root.join("README.md")];
    if let Ok(entries) = std::fs::read_dir(root.join("docs")) {
        let mut docs: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "md"))
            .collect();
        docs.sort();
        files.extend(docs);
    }
    files
}

/// clap's verdict on `args` (after `nerf`): none when it parses (or asks for help or the
/// version), else its error.
fn parse_error(args: &[String]) -> Option<String> {
    let argv = std::iter::once("nerf".to_string()).chain(args.iter().cloned());
    match Cli::try_parse_from(argv) {
        Ok(_) => None,
        Err(e)
            if matches!(
                e.kind(),
                clap::error::ErrorKind::DisplayHelp | clap::error::ErrorKind::DisplayVersion
            ) =>
        {
            None
        }
        Err(e) => Some(e.render().to_string().trim_end().to_string()),
    }
}

#[test]
fn every_documented_command_parses() {
    let mut checked = 0;
    let mut failures = Vec::new();
    let mut in_readme = 0;
    for file in doc_files() {
        let text = std::fs::read_to_string(&file)
            .unwrap_or_else(|e| panic!("cannot read {}: {e}", file.display()));
        let commands = commands_in(&file, &text);
        if file.ends_with("README.md") {
            in_readme = commands.len();
        }
        for c in commands {
            for args in expansions(&shell_words(&c.text)) {
                checked += 1;
                if let Some(error) = parse_error(&args) {
                    failures.push(format!(
                        "{}:{}: `nerf {}` (parsed as {:?}):\n{error}",
                        c.file.strip_prefix(REPO_ROOT).unwrap_or(&c.file).display(),
                        c.line,
                        c.text,
                        args
                    ));
                }
            }
        }
    }
    assert!(in_readme > 0, "no nerf commands found in README.md");
    assert!(
        failures.is_empty(),
        "{} of {checked} documented commands do not parse:\n\n{}",
        failures.len(),
        failures.join("\n\n")
    );
}

#[test]
fn the_scanner_finds_commands_as_a_reader_would() {
    let doc = "text\n\
               ```sh\n\
               # a comment\n\
               cargo run --release -- eval --config lego a=1 \\\n    b=2 # trailing\n\
               nerf render --config box | head\n\
               cargo test --release\n\
               ```\n\
               ```yaml\n\
               nerf not: a command\n\
               ```\n\
               ```\n\
               nerf view --config 'my file.yaml' && echo done\n\
               ```\n";
    let found = commands_in(Path::new("doc.md"), doc);
    let texts: Vec<&str> = found.iter().map(|c| c.text.as_str()).collect();
    assert_eq!(
        texts,
        [
            "eval --config lego a=1 b=2 # trailing",
            "render --config box | head",
            "view --config 'my file.yaml' && echo done"
        ]
    );
    assert_eq!(found.iter().map(|c| c.line).collect::<Vec<_>>(), [4, 6, 13]);
    assert_eq!(
        shell_words(&found[0].text),
        ["eval", "--config", "lego", "a=1", "b=2"]
    );
    assert_eq!(shell_words(&found[1].text), ["render", "--config", "box"]);
    assert_eq!(
        shell_words(&found[2].text),
        ["view", "--config", "my file.yaml"]
    );
    assert_eq!(
        shell_words("targets 'a=[0.25,0.5]' \"b=x y\" c#d <dir> > out"),
        ["targets", "a=[0.25,0.5]", "b=x y", "c#d", "<dir>"]
    );
}

#[test]
fn usage_notation_is_expanded_both_ways() {
    let words = shell_words(
        "eval --config lego [--save-images DIR] [--json] data.image_size=[8,8] --limit N",
    );
    assert_eq!(
        expansions(&words),
        [
            vec![
                "eval",
                "--config",
                "lego",
                "data.image_size=[8,8]",
                "--limit",
                "1"
            ],
            vec![
                "eval",
                "--config",
                "lego",
                "--save-images",
                "1",
                "--json",
                "data.image_size=[8,8]",
                "--limit",
                "1"
            ],
        ]
    );
    // And a wrong command is caught, with clap's reason.
    let error = parse_error(&shell_words("train --config nerf_lego --epoch 5")).unwrap();
    assert!(error.contains("--epoch"), "{error}");
}
