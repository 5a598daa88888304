#!/usr/bin/env bash
# The screening's validation (docs/validation.md, "The screening"): the four presses of the
# finite-element reference (sphere and sticky punch, centred and off-centre, to 6 mm at 1 mm/s)
# on scenarios/validation/block.msh, without screening and with [model] screening = L, then the
# fit on the shallow half and the predictions (scripts/validate_screening.py).
# usage: scripts/validate_screening.sh [OUT] [L...]   (default out/screening, L = 0.01)
#   SCAN=1: the centred presses to 3 mm only (the fit's data), for each L
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/screening}
shift || true
lengths=("${@:-0.01}")
eprop=${EPROP:-target/release/eprop}
[ -x "$eprop" ] || cargo build --release --quiet
mkdir -p "$out"
mesh=$(realpath scenarios/validation/block.msh)
[ -s "$mesh" ] || "$eprop" mesh box --size 0.04,0.04,0.02 --cells 20,20,10 --kind tet -o "$mesh" >/dev/null
for tool in sphere punch; do
  for pos in centre offcentre; do
    x=$([ "$pos" = centre ] && echo 0.02 || echo 0.012)
    if [ "$tool" = sphere ]; then
      shape="shape = \"sphere\""; z=0.025
    else
      shape="shape = \"punch\"
normal = [0, 0, -1]"; z=0.02
    fi
    cat > "$out/${tool}_$pos.toml" <<TOML
[mesh]
file = "$mesh"
unit = "m"
[model]
reading = "continuum"
[tissue]
young = 5000.0
[[fixed]]
group = "zmin"
[[tool]]
$shape
radius = 0.005
start = [$x, 0.02, $z]
velocity = [0.0, 0.0, -0.001]
[time]
end = 6.0
dt = 0.025
[output]
every = 20
TOML
  done
done
run() { # dir, case, extra --set
  local dir=$1 case=$2; shift 2
  mkdir -p "$dir"
  "$eprop" run "$out/$case.toml" -q "$@" -o "$dir/$case.h5" --overwrite >/dev/null
}
cases="sphere_centre sphere_offcentre punch_centre punch_offcentre"
[ "${SCAN:-0}" = 1 ] && cases="sphere_centre punch_centre"
end=()
[ "${SCAN:-0}" = 1 ] && end=(--set time.end=3.0)
for case in $cases; do
  [ -s "$out/none/$case.h5" ] || run "$out/none" "$case" "${end[@]}"
  for l in "${lengths[@]}"; do
    run "$out/l$l" "$case" --set "model.screening=$l" "${end[@]}"
  done
done
/usr/bin/python3 scripts/validate_screening.py "$out" "${lengths[@]}"
