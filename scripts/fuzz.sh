#!/usr/bin/env bash
# Mutation-fuzzes every mesh reader for SECONDS each (default 600), one after the other, at low
# priority, from the seeds in tests/data/fuzz-seeds. Panicking inputs land in
# tests/data/fuzz-regressions/ (tests/formats.rs replays both).
# Usage: scripts/fuzz.sh [SECONDS] [READER...]
set -euo pipefail
cd "$(dirname "$0")/.."
secs="${1:-600}"
shift || true
readers=("$@")
[ ${#readers[@]} -eq 0 ] && readers=(gmsh vtk vtu tetgen medit)
cargo build --release --quiet -p eprop-io --example fuzz
bin="${CARGO_TARGET_DIR:-target}/release/examples/fuzz"
corpus=()
[ -d ../shared/meshes/tet ] && corpus=(--corpus ../shared/meshes/tet)
for r in "${readers[@]}"; do
  nice -n 19 "$bin" --reader "$r" --seconds "$secs" "${corpus[@]}" || echo "fuzz: $r stopped abnormally (see the input it wrote)"
done
