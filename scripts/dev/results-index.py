#!/usr/bin/env python3
"""Writes the index of docs/results/ between the markers of docs/results/README.md: for every
results folder (two levels: docs/results/X and docs/results/X/Y that hold a README or a table),
its title (the first heading of its README.md, else of its TABLE.md), the experiments whose
`results` is that folder (the command that remakes it: `mipnerf experiment experiments/NAME`),
and the commits its rows' JSON files name. Run from the repository root:
`python3 scripts/dev/results-index.py`."""
import glob, json, os, re

ROOT = "docs/results"
BEGIN, END = "<!-- BEGIN RESULTS INDEX: scripts/dev/results-index.py -->", "<!-- END RESULTS INDEX -->"


def title(folder):
    for name in ("README.md", "TABLE.md"):
        path = os.path.join(folder, name)
        if os.path.isfile(path):
            for line in open(path, encoding="utf-8"):
                if line.startswith("#"):
                    return line.lstrip("#").strip(), name
    return None, None


def experiments_by_folder():
    out = {}
    for toml in sorted(glob.glob("experiments/*/experiment.toml")):
        text = open(toml, encoding="utf-8").read()
        m = re.search(r'^results\s*=\s*"([^"]+)"', text, re.M)
        if m:
            folder = os.path.normpath(os.path.join(os.path.dirname(toml), m.group(1)))
            out.setdefault(folder, []).append(os.path.basename(os.path.dirname(toml)))
    return out


def commits(folder):
    seen = set()
    for path in glob.glob(os.path.join(folder, "*.json")):
        try:
            data = json.load(open(path, encoding="utf-8"))
        except (OSError, ValueError):
            continue
        c = data.get("commit") if isinstance(data, dict) else None
        if isinstance(c, str) and c:
            seen.add(c[:7])
    return sorted(seen)


def main():
    exps = experiments_by_folder()
    rows = []
    for folder in sorted(glob.glob(os.path.join(ROOT, "*")) + glob.glob(os.path.join(ROOT, "*", "*"))):
        if not os.path.isdir(folder):
            continue
        head, page = title(folder)
        depth = folder.count(os.sep) - ROOT.count(os.sep)
        if head is None and depth > 1:
            continue
        rel = os.path.relpath(folder, ROOT)
        link = f"[{rel}]({rel}/{page})" if page else f"{rel} (no README)"
        runs = ", ".join(f"`experiments/{e}`" for e in exps.get(os.path.normpath(folder), [])) or ""
        rows.append(f"| {link} | {head or ''} | {runs} | {', '.join(commits(folder))} |")
    table = "\n".join(
        [
            BEGIN,
            "| folder | what it shows (its first heading) | made by | commits of its rows |",
            "|---|---|---|---|",
            *rows,
            END,
        ]
    )
    path = os.path.join(ROOT, "README.md")
    text = open(path, encoding="utf-8").read()
    if BEGIN in text:
        text = text[: text.index(BEGIN)] + table + text[text.index(END) + len(END) :]
    else:
        text = text.rstrip() + "\n\n## Every folder\n\n" + table + "\n"
    open(path, "w", encoding="utf-8").write(text)
    print(f"{len(rows)} folders indexed")


if __name__ == "__main__":
    main()
