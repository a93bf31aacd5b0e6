#!/usr/bin/env bash
# The API clean-up item 5: `mipnerf bench` side by side, before and after the kernel-reference and API
# clean-up, on the same machine in one sitting: the two binaries alternate, three rounds each, so
# that drift of the machine hits both alike. Writes docs/results/api/bench-side-by-side.md.
#   BEFORE=path/to/old/mipnerf AFTER=target/release/mipnerf bash experiments/api-refactor/run.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
before=${BEFORE:?the binary built from the commit before}
after=${AFTER:-target/release/mipnerf}
out=docs/results/api/bench-side-by-side.md
rounds=${ROUNDS:-3}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for r in $(seq 1 "$rounds"); do
    for side in before after; do
        bin=${!side}
        "$bin" bench --backend both --preset tiny,small --steps 8 2>/dev/null | grep '^| [a-z]* (' | sed "s/^/$side /" >> "$tmp/rows"
    done
done
{
    echo "# mipnerf bench side by side"
    echo
    echo "Made by \`experiments/api-refactor/run.sh\` on $(date -u +%Y-%m-%d), $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)),"
    echo "GPU rows on lavapipe. before: \`$before\` ($BEFORE_COMMIT), after: \`$after\` ($AFTER_COMMIT); $rounds rounds, alternating;"
    echo "\`mipnerf bench --backend both --preset tiny,small --steps 8\`. Median of the rounds, and the spread (min to max)."
    echo
    echo "| model | backend | before: samples/s | after: samples/s | change | before: rays/s | after: rays/s | change |"
    echo "|---|---|---|---|---|---|---|---|"
    python3 - "$tmp/rows" <<'PY'
import sys, statistics, collections
rows = collections.defaultdict(lambda: {"before": [], "after": []})
for line in open(sys.argv[1]):
    side, rest = line.split(" ", 1)
    cells = [c.strip() for c in rest.strip().strip("|").split("|")]
    model, backend = cells[0], cells[1].split(";")[0].split(" (")[0]
    rows[(model, backend)][side].append((float(cells[3]), float(cells[4])))
for (model, backend), sides in rows.items():
    def stat(side, i):
        v = [x[i] for x in sides[side]]
        return statistics.median(v), min(v), max(v)
    cells = [model, backend]
    for i in (0, 1):
        b, a = stat("before", i), stat("after", i)
        cells += [f"{b[0]:.0f} ({b[1]:.0f}-{b[2]:.0f})", f"{a[0]:.0f} ({a[1]:.0f}-{a[2]:.0f})", f"{100 * (a[0] / b[0] - 1):+.1f}%"]
    print("| " + " | ".join(cells) + " |")
PY
} > "$out"
cat "$out"
