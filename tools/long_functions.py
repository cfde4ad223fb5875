#!/usr/bin/env python3
"""List Rust functions longer than a limit (default 80 lines) outside test code.

The project's rule is "functions at most 80 lines outside tests". Test code is left out:
`tests/` directories, items under `#[cfg(test)]` (inline `mod tests { .. }` and
`#[cfg(test)] mod name;` declarations, whose files are then skipped too).

A function's length counts the lines from its `fn` line to its closing brace, both included.
Comments, strings and char literals are blanked before scanning, so braces inside them do not
count.

Usage: tools/long_functions.py [--max N] [ROOT ...]   (ROOT defaults to crates/*/src)
Exits 1 when a function is over the limit, so CI can run it as a check.
"""

import argparse
import glob
import os
import re
import sys

FN_RE = re.compile(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)")
CFG_TEST_RE = re.compile(r"#\s*\[\s*cfg\s*\(\s*test\s*\)\s*\]")
ATTR_RE = re.compile(r"\s*#\s*\[")
RAW_RE = re.compile(r'b?r(#*)"')
MOD_DECL_RE = re.compile(r"\s*(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+([A-Za-z_][A-Za-z0-9_]*)\s*;")


def blank_non_code(src):
    """Return src with comments, strings and char literals replaced by spaces (newlines kept)."""
    out = list(src)
    i, n = 0, len(src)

    def blank(a, b):
        for k in range(a, b):
            if out[k] != "\n":
                out[k] = " "

    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            blank(i, j)
            i = j
        elif src.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if src.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif src.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            blank(i, j)
            i = j
        elif c in "br" and RAW_RE.match(src, i) and not (i > 0 and (src[i - 1].isalnum() or src[i - 1] == "_")):
            m = RAW_RE.match(src, i)
            end = src.find('"' + m.group(1), m.end())
            end = n if end < 0 else end + 1 + len(m.group(1))
            blank(i, end)
            i = end
        elif c == '"' or (c == "b" and src.startswith('b"', i) and not (i > 0 and (src[i - 1].isalnum() or src[i - 1] == "_"))):
            j = i + (2 if c == "b" else 1)
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            blank(i, j + 1)
            i = j + 1
        elif c == "'":
            # A char literal ('x', '\n', '\u{..}') or a lifetime ('a): only the former is blanked.
            if i + 1 < n and src[i + 1] == "\\":
                j = src.find("'", i + 2)
                j = n if j < 0 else j
                blank(i, j + 1)
                i = j + 1
            elif i + 2 < n and src[i + 2] == "'":
                blank(i, i + 3)
                i += 3
            else:
                i += 1
        else:
            i += 1
    return "".join(out)


def item_end(code, start):
    """End offset of the item starting at `start`: after its matching `}` or its `;`."""
    depth = 0
    i, n = start, len(code)
    while i < n:
        c = code[i]
        if c in "([":
            depth += 1
        elif c in ")]":
            depth -= 1
        elif c == ";" and depth == 0:
            return i + 1, False
        elif c == "{" and depth == 0:
            return matching_brace(code, i) + 1, True
        i += 1
    return n, False


def matching_brace(code, open_at):
    depth = 0
    for i in range(open_at, len(code)):
        if code[i] == "{":
            depth += 1
        elif code[i] == "}":
            depth -= 1
            if depth == 0:
                return i
    return len(code) - 1


def test_ranges(code):
    """Offsets covered by `#[cfg(test)]` items, and the names of `#[cfg(test)] mod name;` files."""
    ranges, test_mods = [], []
    for m in CFG_TEST_RE.finditer(code):
        i = m.end()
        while True:  # further attributes on the same item
            a = ATTR_RE.match(code, i)
            if not a:
                break
            depth, j = 1, a.end()
            while j < len(code) and depth:
                depth += {"[": 1, "]": -1}.get(code[j], 0)
                j += 1
            i = j
        decl = MOD_DECL_RE.match(code, i)
        if decl:
            test_mods.append(decl.group(1))
        end, _ = item_end(code, i)
        ranges.append((m.start(), end))
    return ranges, test_mods


def module_dir(path):
    """Directory holding the files of the modules that `path` declares."""
    base = os.path.basename(path)
    if base in ("mod.rs", "lib.rs", "main.rs"):
        return os.path.dirname(path)
    return os.path.splitext(path)[0]


def long_functions(path, code, limit):
    """(length, path, line, name) of each function of `code` longer than `limit` outside tests."""
    ranges = test_ranges(code)[0]
    line_of = lambda off: code.count("\n", 0, off) + 1
    found = []
    for m in FN_RE.finditer(code):
        if any(a <= m.start() < b for a, b in ranges):
            continue
        end, has_body = item_end(code, m.end())
        if not has_body:
            continue  # a trait method's declaration
        length = line_of(end - 1) - line_of(m.start()) + 1
        if length > limit:
            found.append((length, path, line_of(m.start()), m.group(1)))
    return found


def rust_files(root):
    """The `.rs` files below `root`, leaving out every `tests` directory (integration tests)."""
    for dirpath, dirnames, filenames in os.walk(root):
        if "tests" in os.path.normpath(dirpath).split(os.sep):
            continue
        dirnames[:] = sorted(d for d in dirnames if d != "tests")
        for f in sorted(filenames):
            if f.endswith(".rs"):
                yield os.path.join(dirpath, f)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--max", type=int, default=80, help="longest allowed function, in lines (default 80)")
    ap.add_argument("roots", nargs="*", help="directories to scan (default: crates/*/src)")
    args = ap.parse_args()
    roots = args.roots or sorted(glob.glob("crates/*/src"))
    files = [f for r in roots for f in rust_files(r)]
    sources, skipped = {}, set()
    for f in files:
        with open(f, encoding="utf-8") as fh:
            sources[f] = blank_non_code(fh.read())
        for name in test_ranges(sources[f])[1]:
            d = module_dir(f)
            skipped |= {os.path.normpath(os.path.join(d, name + ".rs")), os.path.normpath(os.path.join(d, name, "mod.rs"))}
    measured = [f for f in files if os.path.normpath(f) not in skipped]
    found = [hit for f in measured for hit in long_functions(f, sources[f], args.max)]
    for length, path, line, name in sorted(found, key=lambda t: (-t[0], t[1], t[2])):
        print(f"{length:5}  {path}:{line}  {name}")
    print(f"{len(found)} function(s) over {args.max} lines in {len(measured)} file(s) measured")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
