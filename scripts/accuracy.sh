#!/usr/bin/env bash
# Accuracy and time of every integrator against euler (BENCHMARKS.md, "Accuracy"): for each
# case the largest relative L2 error of u over the steps (and of a tool's force against
# euler's peak), operator applications per step and seconds (one process, examples/accuracy.rs).
# Cases: 30^3- and 50^3-cell unit boxes with a patch load (conductivity 0.05), the 30^3 box
# under a load table, the SOFA liver (mor_liverFine.vtu, 4293 nodes) with a ramped patch load,
# scenarios/organs/liver_indent.toml (a sphere pressing that liver), the paper's cylinder pressed
# by a sphere. CASES="box_patch liver" runs some of them; KINDS="rkl2 auto" some integrators.
#   scripts/accuracy.sh [OUT_DIR] [SHARED_MESH_DIR]
# ACCURACY=1e-4 sets [integrator] accuracy (default: the default, 1e-3).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-$root/target/accuracy}"
shared="${2:-$root/../shared/meshes}"
mkdir -p "$out"
cd "$root"
source scripts/env.sh
cargo build --release --quiet --example accuracy --bin eprop
bin="$root/target/release/examples/accuracy"
acc=""
if [ -n "${ACCURACY:-}" ]; then acc=$'[integrator]\naccuracy = '"$ACCURACY"; fi
[ -s "$out/box30.msh" ] || target/release/eprop mesh box --cells 30,30,30 -o "$out/box30.msh" >/dev/null
[ -s "$out/box50.msh" ] || target/release/eprop mesh box --cells 50,50,50 -o "$out/box50.msh" >/dev/null
cp "$shared/tet/mor_liverFine.vtu" "$out/liver.vtu"
cp scenarios/cylinder.msh scenarios/cylinder_indent_path.csv "$out/"
printf 't,fx,fy,fz\n0,0,0,0\n3,-1,0.2,0\n6,0.5,0,0.3\n9,0,0,0\n' >"$out/f.csv"
patch='[[fixed]]
group = "xmin"
[[load]]
patch = { center = [1.0, 0.5, 0.5], radius = 0.2 }'
cat >"$out/box_patch.toml" <<TOML
[mesh]
file = "box30.msh"
[model]
reading = "paper"
[material]
conductivity = 0.05
$patch
normal = 1.0
[time]
steps = 10
$acc
TOML
sed 's/box30.msh/box50.msh/' "$out/box_patch.toml" >"$out/box50_patch.toml"
cat >"$out/box_table.toml" <<TOML
[mesh]
file = "box30.msh"
[model]
reading = "paper"
[material]
conductivity = 0.1
$patch
table = "f.csv"
[time]
steps = 16
$acc
TOML
cat >"$out/liver.toml" <<TOML
[mesh]
file = "liver.vtu"
[model]
reading = "paper"
[material]
conductivity = 0.3
[[fixed]]
halfspace = { point = [-4.0, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }
[[load]]
patch = { center = [0.0, 5.2, 0.5], radius = 1.0 }
normal = 1.0
ramp = [[0.0, 0.0], [10.0, 1.0]]
[time]
steps = 20
$acc
TOML
cat >"$out/cylinder_indent.toml" <<TOML
[mesh]
file = "cylinder.msh"
[model]
reading = "paper"
[material]
conductivity = 0.5
[[fixed]]
group = "bottom"
[[tool]]
shape = "sphere"
radius = 0.8
table = "cylinder_indent_path.csv"
[time]
end = 100.0
$acc
TOML
sed 's#../../../shared/meshes/tet/mor_liverFine.vtu#liver.vtu#' scenarios/organs/liver_indent.toml >"$out/liver_indent.toml"
printf '%s\n' "$acc" >>"$out/liver_indent.toml"
for case in ${CASES:-box_patch box50_patch box_table liver liver_indent cylinder_indent}; do
  # shellcheck disable=SC2086
  RAYON_NUM_THREADS=2 "$bin" "$out/$case.toml" ${KINDS:-} | tee "$out/$case.txt"
done
