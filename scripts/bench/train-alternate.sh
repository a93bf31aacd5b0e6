#!/usr/bin/env bash
# Real training, not the bench: two mipnerf binaries train the same fixed number of steps, one
# right after the other, ROUNDS times, so that a shared machine's drift falls on both alike. The
# wall time covers everything a run does (data loading, the occupancy grid's updates, checkpoints),
# which `mipnerf bench` leaves out. It also hashes each run's checkpoint, so a change that must keep
# the bits shows it did.
#   scripts/bench/train-alternate.sh BEFORE_BINARY AFTER_BINARY OUT_DIR ROUNDS -- TRAIN_FLAGS...
# Writes OUT_DIR/{before,after}-N.txt (the run's output), OUT_DIR/lscpu.txt and OUT_DIR/summary.md.
# Nothing else should run meanwhile.
set -euo pipefail
before=$(realpath "$1"); after=$(realpath "$2"); out=$3; rounds=$4; shift 4
[ "${1:-}" = "--" ] && shift
mkdir -p "$out"
out=$(realpath "$out")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
flags=("$@")
echo "train ${flags[*]}" > "$out/command.txt"
train() {
    rm -rf "$work/run"
    local start end
    start=$(date +%s.%N)
    "$1" train "${flags[@]}" --out "$work/run" > "$2" 2>&1
    end=$(date +%s.%N)
    echo "wall_s $(echo "$end - $start" | bc)" >> "$2"
    echo "checkpoint_sha256 $(sha256sum < "$work/run/checkpoint.safetensors" | cut -d' ' -f1)" >> "$2"
}
source "$(dirname "$0")/alternate.sh"
alternate "$before" "$after" "$out" "$rounds" train
python3 - "$out" "$rounds" <<'PY'
import re, statistics, sys
out, rounds = sys.argv[1], int(sys.argv[2])
rows = {}
for which in ("before", "after"):
    for i in range(1, rounds + 1):
        text = open(f"{out}/{which}-{i}.txt").read()
        wall = float(re.search(r"^wall_s ([\d.]+)", text, re.M).group(1))
        sha = re.search(r"^checkpoint_sha256 (\w+)", text, re.M).group(1)
        rows.setdefault(which, []).append((wall, sha))
with open(f"{out}/summary.md", "w") as f:
    f.write(f"wall seconds of each run of `{open(f'{out}/command.txt').read().strip()}` (lower is faster)\n\n")
    f.write("| round | before s | after s | before / after | same checkpoint |\n|---|---|---|---|---|\n")
    ups = []
    for i in range(rounds):
        (b, bs), (a, as_) = rows["before"][i], rows["after"][i]
        ups.append(b / a)
        f.write(f"| {i + 1} | {b:.1f} | {a:.1f} | {b / a:.2f}x | {'yes' if bs == as_ else 'NO'} |\n")
    f.write(f"\nmedian before / after: **{statistics.median(ups):.2f}x**\n")
print(open(f"{out}/summary.md").read())
PY
