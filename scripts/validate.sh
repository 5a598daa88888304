#!/usr/bin/env bash
# The validation of docs/validation.md: the finite-element reference (scripts/fe_reference.py,
# DOLFINx; computed only when scenarios/validation/reference has no force_centre.csv, or with
# FE_REFRESH=1), eprop's presses of the same block (scenarios/validation/centre.toml and
# offcentre.toml on the mesh `eprop mesh box` makes), and the comparison tables
# (scripts/validate_compare.py) in OUT (default out/validation):
#   OUT/centre/force.csv, lines.csv, summary.csv; OUT/offcentre/...; OUT/validation.png
#   (scripts/validate_plot.py, when python3 has matplotlib)
# usage: scripts/validate.sh [OUT]     (CELLS=20,20,10 sets eprop's mesh; LENGTH=1 is the metres
#                                       per eprop length unit: the scenarios are in SI, the
#                                       continuum reading; 1e-3 for a scenario in mm)
# The reference needs python3-dolfinx and python3-gmsh (apt-get install python3-dolfinx
# python3-gmsh; scripts/setup.sh does not install them: only this script needs them, and only to
# recompute the committed reference).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/validation}
ref=scenarios/validation/reference
cells=${CELLS:-20,20,10}
length=${LENGTH:-1}
py=/usr/bin/python3
if [ ! -s "$ref/force_centre.csv" ] || [ "${FE_REFRESH:-0}" = 1 ]; then
  if ! "$py" -c "import dolfinx, gmsh" 2>/dev/null; then
    echo "validate.sh: $ref has no reference and DOLFINx or gmsh's Python module is missing; fix: apt-get install python3-dolfinx python3-gmsh" >&2
    exit 1
  fi
  echo "validate.sh: the finite-element reference (about an hour)"
  "$py" scripts/fe_reference.py --out-dir "$ref" --quiet
fi
eprop=target/release/eprop
[ -x "$eprop" ] || cargo build --release --quiet
mkdir -p "$out"
"$eprop" mesh box --size 0.04,0.04,0.02 --cells "$cells" --kind tet -o scenarios/validation/block.msh --overwrite >/dev/null
for case in centre offcentre; do
  "$eprop" run "scenarios/validation/$case.toml" -q -o "$out/$case.h5" --overwrite >/dev/null
  "$py" scripts/validate_compare.py "$out/$case.h5" --reference "$ref" --case "$case" \
    --length "$length" -o "$out/$case" >/dev/null
  echo "validate.sh: $case: $out/$case/force.csv, lines.csv, summary.csv"
  column -s, -t < "$out/$case/force.csv" | sed 's/^/  /'
done
if "$py" -c "import matplotlib" 2>/dev/null; then
  "$py" scripts/validate_plot.py "$out" -o "$out/validation.png" >/dev/null
  echo "validate.sh: the figure: $out/validation.png (docs/validation_force.png is this figure)"
fi
