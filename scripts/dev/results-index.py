#!/usr/bin/env python3
"""Writes the index of docs/results/ between the markers of docs/results/README.md: for every
results folder (two levels: docs/results/X and docs/results/X/Y that hold a README or a table),
its title (the first heading of its README.md, else of its TABLE.md), the experiments whose
`results` is that folder (the command that remakes it: `mipnerf experiment experiments/NAME`),
the commits its rows' JSON files name, and whether it is current (STATUS names the folders a later
one replaced, and those that record one change). Run from the repository root:
`python3 scripts/dev/results-index.py`."""
import glob, json, os, re

ROOT = "docs/results"
BEGIN, END = "<!-- BEGIN RESULTS INDEX: scripts/dev/results-index.py -->", "<!-- END RESULTS INDEX -->"

# Folders whose claim a later folder replaced, or that record one change rather than the product:
# what the index says of them (every other folder is current).
STATUS = {
    "tri-mip/first-5m": "superseded by tri-mip/recipe-5m (the recipe's first 5 minutes)",
    "tri-mip/fern": "superseded by tri-mip/fern-tv (the recipe with the planes' total variation)",
    "tri-mip/head-tv": "superseded by tri-mip/head-tv-more (the same split, a wider sweep)",
    "tri-mip/ethiopian-head": "superseded by tri-mip/head-30m (the planes regularised)",
    "tri-mip/head-tv-10m": "superseded by tri-mip/head-30m",
    "time-to-quality": "superseded by fast-preset-30m (the fast preset after its sweep)",
    "time-to-quality/repeat": "superseded by fast-preset-30m",
    "fern/before": "history: fern before occupancy-guided sampling",
    "api": "history: the evidence of the API clean-up and the module restructuring",
    "reliability": "history: the reliability rounds' before and after, and the behaviour fingerprints",
    "render-levels": "history: one change (the last level rendered alone)",
    "packing-loops": "history: one change (the bf16 packing loops)",
    "amx-alignment": "history: one change (cache-line alignment for AMX)",
    "amx-k-chunks": "history: one change (AMX over long k)",
    "occupancy-probes": "history: one change (the grid's probes)",
    "expf": "history: one change (the IPE's exp)",
    "hash-grid/fern": "superseded by hash-grid/fern-capped (the recipe for forward-facing photos)",
    "hash-grid/fern-diverged": "history: the runs whose loss climbed, before hash-grid/stability",
    "hash-grid/fern-capped": "superseded by hash-grid/fern-fade (the recipe with the density noise faded)",
}


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
        status = STATUS.get(rel, "current")
        rows.append(f"| {link} | {head or ''} | {runs} | {', '.join(commits(folder))} | {status} |")
    table = "\n".join(
        [
            BEGIN,
            "| folder | what it shows (its first heading) | made by | commits of its rows | status |",
            "|---|---|---|---|---|",
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
