#!/usr/bin/env bash
# The first-hour bar of the first-hour round, run as a user runs it: the README's own-photos steps 2 and 3
# (`mipnerf colmap`, then the train command it prints, then eval) on 40 lego photos of 400 px
# reconstructed by pycolmap with the README's settings (step 1: scripts/data/make-colmap-workspaces.sh
# bar WORKSPACE). Writes the process step's and the run's output, the evaluation's metrics and a
# picture of every held-out photo beside its render to docs/results/own-photos/bar/.
#
#   bash experiments/own-photos-bar/run.sh WORKSPACE WORK_DIR
#
# Needs a release build (cargo build --release --workspace) and, for LPIPS, $MIPNERF_LPIPS_WEIGHTS.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
ws="$(cd "$1" && pwd)"
work="$2"
bin="$root/target/release/mipnerf"
out="$root/docs/results/own-photos/bar"
mkdir -p "$work" "$out"
cd "$work"
rm -rf scene runs/scene
ln -sfn "$ws" workspace
{
  echo "# $(date -u +%FT%TZ), $("$bin" --version), commit $(git -C "$root" rev-parse --short=12 HEAD)$(git -C "$root" diff --quiet HEAD -- crates shaders || echo -dirty)"
  echo "# machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
  echo '$ mipnerf colmap --input workspace --output scene'
  "$bin" colmap --input workspace --output scene
} 2>&1 | tee "$out/process.txt"
cmd="$(grep -A1 '^train with:' "$out/process.txt" | tail -1 | sed 's/^ *//')"
{
  echo "\$ $cmd"
  start=$(date +%s.%N)
  # shellcheck disable=SC2086
  "$bin" ${cmd#mipnerf }
  echo "wall time of train: $(echo "$(date +%s.%N) - $start" | bc) s"
  echo '$ mipnerf eval --run runs/scene'
  "$bin" eval --run runs/scene
} 2>&1 | tee "$out/run.txt"
cp runs/scene/eval/metrics.json "$out/metrics.json"
cp runs/scene/config.toml "$out/config.toml"
cp runs/scene/train_seconds.txt "$out/train_seconds.txt"
# Every held-out photo beside its render (the eval page's pictures).
for f in runs/scene/eval/*_gt.png; do
  stem="$(basename "$f" _gt.png)"
  cp "$f" "$out/${stem}_photo.png"
  cp "runs/scene/eval/$stem.png" "$out/${stem}_render.png"
done
echo "wrote $out"
