#!/usr/bin/env python3
"""How long each test binary of a `scripts/test.sh` log took, longest first, as a Markdown table.

Usage: python3 scripts/bench/test-times.py LOG (the output of `bash scripts/test.sh`, or of `.ci/run`).
Standard library only.
"""
import re, signal, sys
# Piped into `head`, stop quietly where the reader stops.
signal.signal(signal.SIGPIPE, signal.SIG_DFL)
# Pairs each `Running X (target/...)` line of a cargo test log with the next `test result: ... finished in S` line.
cur = None; rows = []
for line in open(sys.argv[1], errors='replace'):
    m = re.search(r'Running (\S+) \(target/[^/]+/deps/([A-Za-z0-9_]+)-', line)
    if m:
        cur = f"{m.group(2)} ({m.group(1)})"
        continue
    m = re.search(r'test result: .* finished in ([0-9.]+)s', line)
    if m and cur:
        rows.append((float(m.group(1)), cur)); cur = None
rows.sort(reverse=True)
print("| test binary | seconds |\n|---|---|")
for t, n in rows:
    if t >= 1.0: print(f"| {n} | {t:.1f} |")
small = [t for t, _ in rows if t < 1.0]
print(f"| {len(small)} more binaries under 1 s each | {sum(small):.1f} |")
print(f"\ntotal of the binaries: {sum(t for t, _ in rows):.0f} s over {len(rows)} binaries")
