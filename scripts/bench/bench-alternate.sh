#!/usr/bin/env bash
# The CPU bench of two mipnerf binaries, alternated, so that a shared machine's drift falls on
# both alike (the bf16 kernels' speed): `mipnerf bench --backend cpu --preset small,paper --precision f32,bf16`
# ROUNDS times for each, before then after, each output kept verbatim. With a fifth argument
# `f32`: `--preset fast,small --precision f32` instead (a change to the f32 path).
#   scripts/bench/bench-alternate.sh BEFORE_BINARY AFTER_BINARY OUT_DIR [ROUNDS] [f32]
# Writes OUT_DIR/{before,after}-N.txt, and OUT_DIR/summary.md: ms/step per row and run, the
# median before / after per row, and (with bf16 rows) the median speed-up of bf16 over f32 per
# binary and preset. Nothing else should run meanwhile.
set -euo pipefail
before=$(realpath "$1"); after=$(realpath "$2"); out=$3; rounds=${4:-3}
rows=(--preset small,paper --precision f32,bf16)
[ "${5:-}" = f32 ] && rows=(--preset fast,small --precision f32)
mkdir -p "$out"
bench() { "$1" bench --backend cpu "${rows[@]}" --steps 10 --render-side 64 > "$2" 2>&1; }
source "$(dirname "$0")/alternate.sh"
alternate "$before" "$after" "$out" "$rounds" bench
python3 - "$out" "$rounds" <<'PY'
import re, statistics, sys
out, rounds = sys.argv[1], int(sys.argv[2])
rows = {}
for which in ("before", "after"):
    for i in range(1, rounds + 1):
        for line in open(f"{out}/{which}-{i}.txt"):
            m = re.match(r"\| (\w+) \(\d+ parameters\) \| CPU \(\d+ threads(, bf16[^)]*)?\) \| ([\d.]+) \|", line)
            if m:
                prec = "bf16" if m.group(2) else "f32"
                rows.setdefault((which, m.group(1), prec), []).append(float(m.group(3)))
keys = sorted({(p, q) for (_, p, q) in rows}, key=lambda k: (k[0], k[1]))
runs = lambda v: ', '.join(f'{x:.1f}' for x in v)
with open(f"{out}/summary.md", "w") as f:
    f.write("ms/step of each run (lower is faster)\n\n")
    f.write("| preset | precision | before ms/step | after ms/step | median before / after |\n|---|---|---|---|---|\n")
    for preset, prec in keys:
        b, a = rows[("before", preset, prec)], rows[("after", preset, prec)]
        f.write(f"| {preset} | {prec} | {runs(b)} | {runs(a)} | **{statistics.median(b) / statistics.median(a):.3f}x** |\n")
    bf16 = sorted({p for p, q in keys if q == "bf16"})
    if bf16:
        f.write("\nspeed-up = f32 ms / bf16 ms of the same run\n\n")
        f.write("| binary | preset | speed-ups | median speed-up |\n|---|---|---|---|\n")
        for which in ("before", "after"):
            for preset in bf16:
                ups = [a / b for a, b in zip(rows[(which, preset, "f32")], rows[(which, preset, "bf16")])]
                f.write(f"| {which} | {preset} | {', '.join(f'{u:.2f}x' for u in ups)} | **{statistics.median(ups):.2f}x** |\n")
print(open(f"{out}/summary.md").read())
PY
