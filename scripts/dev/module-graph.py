#!/usr/bin/env python3
"""The graph of `crate::` references between each crate's top-level modules (tests/module_graph.rs keeps it layered).

For every crate under crates/, each source file belongs to a top-level module (src/foo.rs and
src/foo/**.rs are `foo`; lib.rs and main.rs are the crate root, left out). A module depends on
another when any of its files names `crate::other` (in a `use` or a path; `use crate::{a, b}`
groups included) outside comments. Prints, per crate, the edges, the cycles (strongly connected
components of more than one module), and the source files over a line limit.

Usage: python3 scripts/dev/module-graph.py [--max-lines N] [--check]
  --check: exit 1 when any crate's graph has a cycle or a file is over the limit.
"""

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join(line.split("//", 1)[0] for line in text.splitlines())


def top_module(src: Path, file: Path):
    rel = file.relative_to(src)
    if len(rel.parts) == 1:
        name = rel.stem
        return None if name in ("lib", "main") else name
    return rel.parts[0]


def crate_refs(text: str):
    """Names of the top-level modules a file's code names through `crate::`."""
    out = set()
    for m in re.finditer(r"\bcrate::(\{[^}]*\}|\w+)", text):
        item = m.group(1)
        if item.startswith("{"):
            for part in item[1:-1].split(","):
                part = part.strip()
                if part:
                    out.add(re.split(r"\W", part, maxsplit=1)[0])
        else:
            out.add(item)
    return out


def sccs(nodes, edges):
    """Tarjan's strongly connected components."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in sorted(nodes):
        if v not in index:
            visit(v)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-lines", type=int, default=800)
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    bad = False
    for crate in sorted((ROOT / "crates").iterdir()):
        src = crate / "src"
        if not src.is_dir():
            continue
        files = sorted(src.rglob("*.rs"))
        modules = {top_module(src, f) for f in files} - {None}
        edges = {}
        for f in files:
            m = top_module(src, f)
            if m is None:
                continue
            for r in crate_refs(strip_comments(f.read_text())):
                if r in modules and r != m:
                    edges.setdefault(m, set()).add(r)
        print(f"# {crate.name}: {len(modules)} top-level modules")
        for m in sorted(modules):
            print(f"  {m} -> {', '.join(sorted(edges.get(m, ()))) or '(none)'}")
        cycles = [c for c in sccs(modules, edges) if len(c) > 1]
        for c in cycles:
            print(f"  CYCLE: {' <-> '.join(c)}")
        if not cycles:
            print("  no cycles")
        bad |= bool(cycles)
        over = [(n, f) for f in files if (n := len(f.read_text().splitlines())) > args.max_lines]
        if over:
            print(f"  files over {args.max_lines} lines:")
            for n, f in sorted(over, reverse=True):
                print(f"    {n:5} {f.relative_to(ROOT)}")
            bad = True
        else:
            print(f"  no file over {args.max_lines} lines")
        print()
    if args.check and bad:
        sys.exit(1)


if __name__ == "__main__":
    main()
