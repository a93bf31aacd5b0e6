#!/usr/bin/env bash
# The default density threshold of `mipnerf export --mesh` (cli/src/export.rs, DEFAULT_THRESHOLD):
# meshes of two runs at thresholds 5, 10 and 25.
# - the demo scene (64 px, 20 views), fast preset, 1500 steps (as crates/mipnerf-cli/tests/export.rs):
#   the distance of the sphere's vertices to the true sphere;
# - lego256 (4 scales), fast preset, 5 minutes: the vertices outside lego's extent (floaters).
# Usage: experiments/export-threshold/run.sh MIPNERF LEGO256 WORKDIR > docs/results/export/thresholds.txt
set -euo pipefail
M=$1; LEGO=$2; W=$3
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$W"
echo "# mipnerf export --mesh thresholds; binary: $("$M" --version)"
if [ ! -f "$W/demo/checkpoint.safetensors" ]; then
  "$M" --quiet demo --out "$W/gen" --size 64 --views 20 --steps 1 --preset tiny --backend cpu > /dev/null
  "$M" --quiet train --data "$W/gen/data" --out "$W/demo" --preset fast --steps 1500 --backend cpu
fi
if [ ! -f "$W/lego/checkpoint.safetensors" ]; then
  "$M" --quiet train --data "$LEGO" --out "$W/lego" --preset fast --time-budget 5m --backend cpu
fi
for t in 5 10 25; do
  "$M" export --run "$W/demo" --mesh "$W/demo-$t.ply" --resolution 64 --threshold $t --overwrite
  python3 "$here/plystats.py" sphere "$W/demo-$t.ply"
  "$M" export --run "$W/lego" --mesh "$W/lego-$t.ply" --resolution 128 --threshold $t --overwrite
  python3 "$here/plystats.py" lego "$W/lego-$t.ply"
done
