#!/usr/bin/env bash
# The CPU bench of two mipnerf binaries, alternated, so that a shared machine's drift falls on
# both alike (issue 40): `mipnerf bench --backend cpu --preset small,paper --precision f32,bf16`
# ROUNDS times for each, before then after, each output kept verbatim.
#   scripts/bench-alternate.sh BEFORE_BINARY AFTER_BINARY OUT_DIR [ROUNDS]
# Writes OUT_DIR/{before,after}-N.txt, and OUT_DIR/summary.md: ms/step per row and run, and the
# median speed-up of bf16 over f32 per binary and preset. Nothing else should run meanwhile.
set -euo pipefail
before=$(realpath "$1"); after=$(realpath "$2"); out=$3; rounds=${4:-3}
mkdir -p "$out"
bench() { "$1" bench --backend cpu --preset small,paper --precision f32,bf16 --steps 10 --render-side 64 > "$2" 2>&1; }
source "$(dirname "$0")/alternate.sh"
alternate "$before" "$after" "$out" "$rounds" bench
python3 - "$out" "$rounds" <<'PY'
import re, statistics, sys
out, rounds = sys.argv[1], int(sys.argv[2])
rows = {}
for which in ("before", "after"):
    for i in range(1, rounds + 1):
        for line in open(f"{out}/{which}-{i}.txt"):
            m = re.match(r"\| (small|paper) \(\d+ parameters\) \| CPU \(2 threads(, bf16[^)]*)?\) \| ([\d.]+) \|", line)
            if m:
                prec = "bf16" if m.group(2) else "f32"
                rows.setdefault((which, m.group(1), prec), []).append(float(m.group(3)))
with open(f"{out}/summary.md", "w") as f:
    f.write("ms/step of each run (lower is faster); speed-up = f32 ms / bf16 ms of the same run\n\n")
    f.write("| binary | preset | f32 ms/step | bf16 ms/step | speed-ups | median speed-up |\n|---|---|---|---|---|---|\n")
    for which in ("before", "after"):
        for preset in ("small", "paper"):
            f32, bf = rows[(which, preset, "f32")], rows[(which, preset, "bf16")]
            ups = [a / b for a, b in zip(f32, bf)]
            f.write(f"| {which} | {preset} | {', '.join(f'{v:.1f}' for v in f32)} | {', '.join(f'{v:.1f}' for v in bf)} "
                    f"| {', '.join(f'{u:.2f}x' for u in ups)} | **{statistics.median(ups):.2f}x** |\n")
print(open(f"{out}/summary.md").read())
PY
