#!/usr/bin/env python3
"""The library's public items: how many each crate declares, who names them, and how many
merging crates could make internal (issue 47, docs/library.md#public-items).

    scripts/public_items.py            the count per crate and who names the items
    scripts/public_items.py --merges   also the best merge of the crates into 5..10 crates

The count is the issue's: lines that declare a `pub fn|struct|enum|const|mod|trait|type|
static|use`, counted textually in the library's .rs files (the facade's `src/` and every
`crates/*/src`), which also takes a struct field named `model` for a `mod`.
`tests/public_items.rs` holds the per-crate counts equal to docs/library.md's table.

Who names an item is a textual search too, so it errs towards "needed": an item counts as
named by a crate when its name occurs as a word anywhere in that crate's files (a method
`len` is "named" by every crate that has any `len`). What a merge could make `pub(crate)`
is therefore counted low rather than high; that the items are needed at all was the
compiler's word, not this script's (docs/library.md#public-items).
"""
import collections
import glob
import os
import re
import sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
COUNTED = re.compile(r"^\s*pub (fn|struct|enum|const|mod|trait|type|static|use)")
DECLARED = re.compile(
    r"^\s*pub (fn|struct|enum|const|mod|trait|type|static)\b\s*([A-Za-z_][A-Za-z0-9_]*)"
)
WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def owner(path):
    """The crate a file belongs to: a library crate, the facade, the command or the root's
    own tests and examples."""
    if path.startswith("crates/"):
        return path.split("/")[1]
    if path.startswith("src/"):
        return "facade"
    if path.startswith("apps/"):
        return "command"
    return "root tests and examples"


def library_file(path):
    return path.startswith("src/") or (path.startswith("crates/") and "/src/" in path)


def main():
    os.chdir(ROOT)
    files = [
        f
        for f in glob.glob("**/*.rs", recursive=True)
        if not f.startswith("target/") and "/target/" not in f
    ]
    text = {f: open(f, encoding="utf-8").read() for f in files}
    words_by_crate = collections.defaultdict(set)
    for f in files:
        words_by_crate[owner(f)].update(WORD.findall(text[f]))

    counted = collections.Counter()
    # (declaring crate, the other crates that name it) for each declared item.
    items = []
    for f in sorted(files):
        if not library_file(f):
            continue
        for line in text[f].split("\n"):
            if not COUNTED.match(line):
                continue
            counted[owner(f)] += 1
            declared = DECLARED.match(line)
            if declared:
                crate, name = owner(f), declared.group(2)
                readers = {c for c, words in words_by_crate.items() if c != crate and name in words}
                items.append((crate, frozenset(readers)))

    print("lines that declare a public item, per crate:")
    for crate in sorted(counted):
        print(f"  {crate:16} {counted[crate]:4}")
    print(f"  {'total':16} {sum(counted.values()):4}")

    outside = {"command", "root tests and examples"}
    library = sorted(c for c in counted if c != "facade")
    named_outside = sum(1 for _, readers in items if readers & outside)
    # An item the facade names is re-exported by it, so it stays public whatever is merged.
    only_library = [
        (crate, readers)
        for crate, readers in items
        if readers and not readers & outside and "facade" not in readers
    ]
    by_command = sum(1 for _, readers in items if "command" in readers)
    facade_only = sum(
        1 for _, readers in items if not readers & outside and "facade" in readers
    )
    print(f"declared items: {len(items)}; named by the command: {by_command}; by the root "
          f"tests or examples and not the command: {named_outside - by_command}; only by "
          f"other library crates: {len(only_library)}; re-exported by the facade: {facade_only}; "
          f"by none: {len(items) - named_outside - len(only_library) - facade_only}")

    if "--merges" in sys.argv:
        merges(library, only_library, sum(counted.values()))


def partitions(crates):
    if not crates:
        yield []
        return
    first, rest = crates[0], crates[1:]
    for partition in partitions(rest):
        for i in range(len(partition)):
            yield partition[:i] + [[first] + partition[i]] + partition[i + 1:]
        yield [[first]] + partition


def merges(library, only_library, total):
    """For each number of library crates, the merge that leaves the fewest public items: an
    item read only by crates merged with its own becomes `pub(crate)`."""
    kinds = collections.Counter((crate, readers) for crate, readers in only_library)
    best = {}
    for partition in partitions(library):
        if len(partition) < 5:
            continue
        group = {c: i for i, part in enumerate(partition) for c in part}
        hidden = sum(
            n for (crate, readers), n in kinds.items()
            if all(group[r] == group[crate] for r in readers)
        )
        if hidden > best.get(len(partition), (-1, None))[0]:
            best[len(partition)] = (hidden, partition)
    print(f"all library crates in one: {total - len(only_library)} left")
    print("best merge for each number of library crates (crates merged, items left):")
    for n in sorted(best):
        hidden, partition = best[n]
        merged = [" + ".join(p) for p in partition if len(p) > 1]
        print(f"  {n:2} crates: {total - hidden:4} left ({hidden} internal) merging {'; '.join(merged)}")


if __name__ == "__main__":
    main()
