#!/usr/bin/env python3
"""What a newcomer meets in the tree at each of the given commits, as one Markdown table:

    python3 scripts/dev/structure-report.py a71b2a1 HEAD

Read from git alone (`git ls-tree`, `git show`), so any commit can be measured without checking
it out. Rust functions are found by their `fn` line and the brace that closes them (comments
and string literals with braces are rare enough here to be ignored; the counts are a guide, not
a parser's).
"""
import re
import subprocess
import sys


def git(*args):
    return subprocess.run(["git", *args], check=True, capture_output=True, text=True).stdout


def files(commit):
    return [f for f in git("ls-tree", "-r", "--name-only", commit).splitlines()]


def show(commit, path):
    try:
        return git("show", f"{commit}:{path}")
    except subprocess.CalledProcessError:
        return ""


FN = re.compile(r"^\s*(pub(\([a-z]+\))?\s+)?(const\s+)?(unsafe\s+)?(extern\s+\"C\"\s+)?fn\s+(\w+)")


def functions(text):
    """(name, lines, parameters) of each function with a body."""
    lines = text.split("\n")
    out = []
    i = 0
    while i < len(lines):
        m = FN.match(lines[i])
        if not m:
            i += 1
            continue
        # The signature runs to the first `{` or `;` at depth 0 of parentheses.
        sig, j, depth = "", i, 0
        while j < len(lines):
            sig += lines[j] + "\n"
            if "{" in lines[j] or lines[j].rstrip().endswith(";"):
                break
            j += 1
        if "{" not in sig:
            i = j + 1
            continue
        params = ""
        if "(" in sig:
            start, depth = sig.find("("), 0
            for end in range(start, len(sig)):
                depth += {"(": 1, ")": -1}.get(sig[end], 0)
                if depth == 0:
                    break
            params = sig[start + 1 : end]
        n_params = len([p for p in split_params(params) if p.strip() and p.strip() not in ("self", "&self", "&mut self", "mut self")])
        braces, k = 0, i
        started = False
        while k < len(lines):
            braces += lines[k].count("{") - lines[k].count("}")
            if lines[k].count("{"):
                started = True
            if started and braces <= 0:
                break
            k += 1
        out.append((m.group(6), k - i + 1, n_params))
        i += 1
    return out


def split_params(params):
    depth, cur, parts = 0, "", []
    for ch in params:
        if ch in "(<[":
            depth += 1
        elif ch in ")>]":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
        else:
            cur += ch
    parts.append(cur)
    return parts


def report(commit):
    all_files = files(commit)
    rust = [f for f in all_files if f.endswith(".rs") and (f.startswith("crates/") or f.startswith("src/") or f.startswith("tests/") or f.startswith("examples/"))]
    lib_rust = [f for f in rust if "/src/" in f or f.startswith("src/")]
    sizes = {f: show(commit, f).count("\n") for f in rust}
    longest_file = max(sizes.items(), key=lambda kv: kv[1])
    fns = []
    allows = {"too_many_arguments": 0, "dead_code": 0}
    for f in lib_rust:
        text = show(commit, f)
        fns += [(f, *fn) for fn in functions(text)]
        allows["too_many_arguments"] += len(re.findall(r"allow\(clippy::too_many_arguments\)", text))
        allows["dead_code"] += len(re.findall(r"allow\(dead_code\)", text))
    cargo = show(commit, "Cargo.toml")
    workspace_tma = 'too_many_arguments = "allow"' in cargo
    long_fns = [x for x in fns if x[2] > 120]
    many_params = [x for x in fns if x[3] > 7]
    readme = show(commit, "README.md").count("\n")
    docs = [f for f in all_files if f.endswith(".md") or f.endswith(".rs") or f.endswith(".wgsl") or f.endswith(".sh")]
    issue_refs = sum(len(re.findall(r"\b[Ii]ssue \d+", show(commit, f))) for f in docs if not f.startswith("docs/results/"))
    results = sorted({f.split("/")[2] for f in all_files if f.startswith("docs/results/") and f.count("/") >= 3})
    results_readme = sum(1 for r in results if f"docs/results/{r}/README.md" in all_files)
    scripts_top = [f for f in all_files if f.startswith("scripts/") and f.count("/") == 1]
    facade = show(commit, "src/lib.rs")
    reexports_crates = len(re.findall(r"^pub use mipnerf_(core|gpu);", facade, re.M))
    core_lines = sum(v for f, v in sizes.items() if f.startswith("crates/mipnerf-core/src/"))
    # The data formats: in the core's data/ folder until they moved to the mipnerf-data crate.
    data_lines = sum(v for f, v in sizes.items() if f.startswith("crates/mipnerf-core/src/data/"))
    data_crate_lines = sum(v for f, v in sizes.items() if f.startswith("crates/mipnerf-data/src/"))
    return {
        "README lines": readme,
        "Rust files over 800 lines": sum(1 for v in sizes.values() if v > 800),
        "longest Rust file": f"{longest_file[0]} ({longest_file[1]})",
        "functions over 120 lines (library code)": f"{len(long_fns)}: " + ", ".join(f"{f.split('/')[-1]} {n} ({l})" for f, n, l, _ in sorted(long_fns, key=lambda x: -x[2])[:6]),
        "functions of more than 7 parameters (library code)": len(many_params),
        "`too_many_arguments` allowed for the workspace": "yes" if workspace_tma else "no",
        "`allow(clippy::too_many_arguments)` in code": allows["too_many_arguments"],
        "`allow(dead_code)` in code": allows["dead_code"],
        "\"issue N\" in code and docs (results aside)": issue_refs,
        "results folders / with a README": f"{len(results)} / {results_readme}",
        "files at the top of scripts/": len(scripts_top),
        "the facade re-exports whole crates": reexports_crates,
        "core lines / of them data formats (core/data/)": f"{core_lines} / {data_lines}",
        "mipnerf-data lines (the data formats' own crate)": data_crate_lines,
        "ARCHITECTURE.md lines": show(commit, "ARCHITECTURE.md").count("\n"),
    }


def main():
    commits = sys.argv[1:] or ["HEAD"]
    rows = [report(c) for c in commits]
    names = [git("rev-parse", "--short", c).strip() for c in commits]
    print("| measure | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for key in rows[0]:
        print(f"| {key} | " + " | ".join(str(r[key]) for r in rows) + " |")


if __name__ == "__main__":
    main()
