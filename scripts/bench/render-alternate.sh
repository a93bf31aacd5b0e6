#!/usr/bin/env bash
# Rendering time of two mipnerf binaries on one trained run, alternated so that a shared
# machine's drift falls on both alike: `eval` of the run's test split (no LPIPS) and `render` of
# a spiral (or orbit) path, ROUNDS times each.
#   scripts/bench/render-alternate.sh BEFORE_BINARY AFTER_BINARY RUN_DIR OUT_DIR [ROUNDS] [PATH_KIND]
# Writes OUT_DIR/{before,after}-N.txt (seconds of each command), OUT_DIR/summary.md (medians and
# their ratio) and OUT_DIR/identical.txt: whether the two binaries' images and metrics are the
# same bytes. Each binary works on its own copy of the run. Nothing else should run meanwhile.
set -euo pipefail
before=$(realpath "$1"); after=$(realpath "$2"); run=$(realpath "$3"); out=$4; rounds=${5:-3}
kind=${6:-spiral}
mkdir -p "$out"
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
# Each binary's copy is called `run` in its own folder, so that the pages eval writes, which name
# the run, are comparable byte for byte.
mkdir "$scratch/before" "$scratch/after"
cp -r "$run" "$scratch/before/run"; cp -r "$run" "$scratch/after/run"
seconds() { local t0 t1; t0=$(date +%s.%N); "$@" > /dev/null 2>&1; t1=$(date +%s.%N); echo "$t1 - $t0" | bc; }
measure() {
    local bin=$1 file=$2 which
    which=$(basename "$file" | cut -d- -f1)
    (
        echo "binary: $("$bin" --version)"
        cd "$scratch/$which"
        echo "eval_s: $(seconds "$bin" eval --run run --no-lpips --quiet)"
        echo "render_s: $(seconds "$bin" render --run run --out frames --path "$kind" --frames 8 --overwrite --quiet)"
    ) > "$file"
}
source "$(dirname "$0")/alternate.sh"
alternate "$before" "$after" "$out" "$rounds" measure
{
    for d in run/eval frames; do
        for f in $(cd "$scratch/before/$d" && ls); do
            if [ -f "$scratch/before/$d/$f" ] && ! cmp -s "$scratch/before/$d/$f" "$scratch/after/$d/$f"; then
                echo "differ: $d/$f"
            fi
        done
        echo "compared: $(ls "$scratch/before/$d" | wc -l) files in $d"
    done
} > "$out/identical.txt"
python3 - "$out" <<'PY'
import glob, os, statistics, sys
out = sys.argv[1]
times = {}
for path in sorted(glob.glob(f"{out}/*-[0-9]*.txt")):
    which = os.path.basename(path).split("-")[0]
    for key, _, value in (line.partition(": ") for line in open(path)):
        if key.endswith("_s"):
            times.setdefault((which, key), []).append(float(value))
with open(f"{out}/summary.md", "w") as f:
    f.write("| command | before, s | after, s | median before / median after |\n|---|---|---|---|\n")
    for key, name in (("eval_s", "eval (test split, no LPIPS)"), ("render_s", "render (8 path frames)")):
        b, a = times[("before", key)], times[("after", key)]
        f.write(f"| {name} | {', '.join(f'{v:.2f}' for v in b)} | {', '.join(f'{v:.2f}' for v in a)} "
                f"| **{statistics.median(b) / statistics.median(a):.3f}x** |\n")
print(open(f"{out}/summary.md").read())
PY
cat "$out/identical.txt"
