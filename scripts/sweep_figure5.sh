#!/usr/bin/env bash
# The paper's force-displacement study (figure 5): the cylinder pressed on its side with normal
# forces 0.1 .. 1.0, damping g = 1, 4, 6, literal reading (k_e = 0), 20 iterations each; draws
# displacement at iteration 20 against force, one curve per g.
# usage: scripts/sweep_figure5.sh [OUT_DIR]   (default out/figure5); prints the PNG path
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-out/figure5}"
mkdir -p "$out"
eprop="$here/target/release/eprop"
py="$here/.venv/bin/python"
[ -x "$py" ] || py=/usr/bin/python3
[ -x "$eprop" ] || { echo "sweep_figure5.sh: build first (scripts/setup.sh)" >&2; exit 1; }
"$eprop" mesh cylinder -o "$out/cylinder.msh" >/dev/null
files=()
for g in 1 4 6; do
  for f in 0.1 0.2 0.4 0.6 0.8 1.0; do
    sc="$out/g${g}_f${f}.toml"
    cat > "$sc" <<TOML
# figure 5 point: damping g = $g, normal force $f, 20 iterations, k_e = 0 (the paper's reading)
[mesh]
file = "cylinder.msh"
[material]
mass = 1.0
damping = $g
conductivity = 0.05
[model]
reading = "paper"
stiffness = 0.0
[[fixed]]
group = "bottom"
[[load]]
nearest = [1.0, 0.0, 2.0]
normal = $f
[time]
steps = 20
dt = 0.1
[output]
every = 20
TOML
    RAYON_NUM_THREADS=1 "$eprop" run "$sc" -q --overwrite -o "$out/g${g}_f${f}.h5" >/dev/null
    files+=("$out/g${g}_f${f}.h5")
  done
done
"$py" "$here/scripts/force_displacement.py" "${files[@]}" --at-step 1 -o "$out/figure5.png"
