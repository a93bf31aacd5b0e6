#!/bin/bash
# The time of the same training steps with subnormals kept and flushed, in pairs, from
# one trained checkpoint (where the gradients in empty space have had time to go subnormal): each
# round copies RUN, resumes it for STEPS more steps once with --keep-subnormals and once with
# --flush-subnormals, and prints the training seconds each took (train_seconds.txt's growth).
# Alternating the two in rounds spreads a shared machine's drift over both.
#
# Usage: bash scripts/bench/subnormals-paired.sh BINARY RUN STEPS ROUNDS
set -euo pipefail
bin=$(realpath "$1"); run=$2; steps=$3; rounds=$4
done_steps=$(grep -m1 '^steps' "$run/config.toml" | tr -dc 0-9)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "| round | subnormals | steps | training seconds | ms/step |"
echo "|---|---|---|---|---|"
for round in $(seq 1 "$rounds"); do
    for mode in keep flush; do
        rm -rf "$work/run" && cp -r "$run" "$work/run"
        rm -f "$work/run/train.lock"
        before=$(cat "$work/run/train_seconds.txt")
        "$bin" train --out "$work/run" --resume --steps $((done_steps + steps)) "--$mode-subnormals" --quiet >/dev/null 2>&1
        after=$(cat "$work/run/train_seconds.txt")
        python3 -c "s=$after-$before; print(f'| $round | $mode | $steps | {s:.1f} | {1000*s/$steps:.1f} |')"
    done
done
