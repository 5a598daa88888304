#!/usr/bin/env bash
# The fits of the elastic-foundation law (law = "foundation", docs/tools.md) of
# docs/validation.md, on the centred press to 4 mm only (the reference's rows a fit may use), in
# OUT (default out/validation_fit). The kinematic law (the default) is fitted with `eprop fit`
# on force and profile curves together (docs/fit.md) and scripts/validate_screening.sh.
#   1. young against the force-indentation curve (force_centre.csv to 4 mm). Under the
#      foundation law the tool's force depends only on young, beta and the foundation depth h
#      (docs/tools.md), not on u, so the
#      evaluations press fast (0.1 m/s, dt = 1 ms) with the propagation off (coupling 0): the
#      same force at the same depth, 0.05 s per evaluation instead of a minute.
#   2. coupling against the reference's |u| at mid-depth under the indenter (0.02, 0.02, 0.01),
#      node 2426 of the 20 x 20 x 10 block, at t = depth / (1 mm/s) (several minutes).
# usage: scripts/validate_fit.sh [OUT]    (the block as scripts/validate.sh makes it; FORCE_ONLY=1
#                                          skips the displacement fit)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/validation_fit}
ref=scenarios/validation/reference
eprop=target/release/eprop
[ -x "$eprop" ] || cargo build --release --quiet
mkdir -p "$out"
"$eprop" mesh box --size 0.04,0.04,0.02 --cells 20,20,10 --kind tet -o scenarios/validation/block.msh --overwrite >/dev/null
{ echo "indentation,force"; tail -n +2 "$ref/force_centre.csv" | cut -d, -f1,2; } > "$out/force.csv"
awk -F, 'NR > 1 && $2 == "vertical" && $5 == 0.01 && $1 <= 0.004 {
  printf "%.6g,%.7g\n", $1 / 0.001, sqrt($6 * $6 + $7 * $7 + $8 * $8) }' "$ref/lines_centre.csv" |
  { echo "time,displacement"; cat; } > "$out/displacement.csv"
law=(--set tool.1.law=foundation)
fast=("${law[@]}" --set 'tool.1.velocity=[0.0,0.0,-0.1]' --set time.dt=1e-3 --set time.end=0.0401
      --set material.conductivity=1e-5 --set model.coupling=0)
"$eprop" fit scenarios/validation/centre.toml --data "$out/force.csv" --param young=1e3:1e6 \
  -o "$out/young" --overwrite "${fast[@]}"
# beta with young (several starts): beta goes to its lower bound, the curve is not convex enough
for b in 0.01 1 5; do
  "$eprop" fit scenarios/validation/centre.toml --data "$out/force.csv" --param young=1e3:1e6 \
    --param beta=1e-4:20 --start young=1.87e4 --start beta=$b -o "$out/young_beta_$b" \
    --overwrite --no-plot -q "${fast[@]}"
done
# young with the foundation depth: only young / h matters (beyond the smoothing at first touch)
"$eprop" fit scenarios/validation/centre.toml --data "$out/force.csv" --param young=1e3:1e6 \
  --param tool.1.foundation=0.002:0.1 -o "$out/young_foundation" --overwrite --no-plot -q "${fast[@]}"
[ "${FORCE_ONLY:-0}" = 1 ] && exit 0
"$eprop" fit scenarios/validation/centre.toml --data "$out/displacement.csv" --node 2426 \
  --param coupling=1:1000 --start coupling=15 --set time.end=4.0 -o "$out/coupling" --overwrite "${law[@]}"
