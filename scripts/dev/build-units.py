#!/usr/bin/env python3
"""Compare two cold builds' `cargo ... --timings` reports: the total compile time of their units,
the crates one has that the other lacks, and the units that moved most.

    python3 scripts/dev/build-units.py BEFORE_TARGET_DIR AFTER_TARGET_DIR
"""
import glob
import json
import re
import sys


def units(target_dir):
    report = sorted(glob.glob(f"{target_dir}/cargo-timings/cargo-timing-*.html"))[-1]
    text = open(report).read()
    data = json.loads(re.search(r"const UNIT_DATA = (\[.*?\]);\n", text, re.S).group(1))
    return {(u["name"], u["version"], u["target"], u["mode"]): u["duration"] for u in data}


def main():
    before, after = units(sys.argv[1]), units(sys.argv[2])
    print(f"units: {len(before)} -> {len(after)}; their compile time summed: "
          f"{sum(before.values()):.0f} s -> {sum(after.values()):.0f} s")
    gone = [k for k in before if k not in after]
    print(f"only before: {sum(before[k] for k in gone):.0f} s in "
          + ", ".join(sorted({f'{k[0]} {k[1]}' for k in gone})))
    moved = sorted(((before[k] - after[k], k) for k in before if k in after), reverse=True)[:12]
    print("| unit | before (s) | after (s) |\n|---|---|---|")
    for _, k in moved:
        print(f"| {k[0]} {k[2].strip()} | {before[k]:.1f} | {after[k]:.1f} |")


if __name__ == "__main__":
    main()
