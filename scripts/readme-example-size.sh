#!/usr/bin/env bash
# Size of the README's library example (the rust block under "Use it as a library", also the
# doctest of src/lib.rs): lines, use statements, names imported, BackendSetup fields written.
# Issue 28 asks for it before and after the smaller public API.
set -euo pipefail
cd "$(dirname "$0")/.."
ex=$(awk '/^## Use it as a library/,/^## Results/' README.md | awk '/^```rust/{f=1;next} /^```/{f=0} f')
echo "## $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- README.md || echo -dirty): scripts/readme-example-size.sh"
echo "lines (non-blank, comments included): $(grep -c . <<<"$ex")"
echo "use statements: $(grep -c '^use ' <<<"$ex")"
echo "names imported: $(grep '^use ' <<<"$ex" | sed 's/.*::{\{0,1\}//; s/[{};]//g' | tr ',' '\n' | grep -c .)"
echo "BackendSetup fields written: $(awk '/BackendSetup \{/,/^\};/' <<<"$ex" | grep -cE '^\s+[a-z_]+(:|,)')"
