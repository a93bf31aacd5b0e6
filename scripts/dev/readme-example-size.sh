#!/usr/bin/env bash
# Size of the library guide's example (docs/guide/library.md's rust block, also the doctest of
# src/lib.rs): lines, use statements, names imported, BackendSetup fields written.
set -euo pipefail
cd "$(dirname "$0")/../.."
ex=$(awk '/^```rust/{f=1;next} /^```/{f=0} f' docs/guide/library.md)
echo "## $(git rev-parse --short HEAD)$(git diff --quiet HEAD -- docs/guide/library.md || echo -dirty): scripts/dev/readme-example-size.sh"
echo "lines (non-blank, comments included): $(grep -c . <<<"$ex")"
echo "use statements: $(grep -c '^use ' <<<"$ex")"
echo "names imported: $(grep '^use ' <<<"$ex" | sed 's/.*::{\{0,1\}//; s/[{};]//g' | tr ',' '\n' | grep -c .)"
echo "BackendSetup fields written: $(awk '/BackendSetup \{/,/^\};/' <<<"$ex" | grep -cE '^\s+[a-z_]+(:|,)')"
