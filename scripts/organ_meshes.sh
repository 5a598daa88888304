#!/usr/bin/env bash
# Makes the tetrahedral volume meshes of scenarios/organs/{kidney,heart,prostate}.toml from the
# shared organ surfaces with Debian's tetgen. eprop reads tetgen's .node/.ele/.face directly; the
# scenarios scale the coordinates from metres to millimetres ([mesh] scale = 1000).
# Output: scenarios/organs/meshes/NAME.{node,ele,face} (not in git). Safe to run again: meshes
# that exist are kept; each appears whole or not at all.
#   scripts/organ_meshes.sh [SHARED_MESH_DIR]   (default: ../shared/meshes beside the checkout)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
shared="${1:-$root/../shared/meshes}"
out="$root/scenarios/organs/meshes"
if [ ! -d "$shared/surface" ]; then
  echo "organ_meshes: $shared/surface not found; fix: give the shared mesh directory as the argument" >&2
  exit 1
fi
if ! command -v tetgen >/dev/null; then
  echo "organ_meshes: tetgen not found; fix: apt-get install tetgen (scripts/setup.sh does)" >&2
  exit 1
fi
mkdir -p "$out"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# name, surface file, tetgen switches. p: mesh the closed surface as it is; Y: no Steiner points
# on it. No quality refinement (q): it adds many tiny cells along the finely triangulated
# surfaces, and the smallest cell sets the stable substep of the explicit propagation.
make() {
  local name="$1" surf="$2" switches="$3"
  if [ -s "$out/$name.ele" ] && [ -s "$out/$name.node" ]; then
    echo "organ_meshes: $out/$name.ele exists"
    return
  fi
  cp "$shared/surface/$surf" "$work/$name.off"
  (cd "$work" && tetgen "-$switches" -Q "$name.off" >/dev/null)
  # each file copied under a temporary name, then renamed in place (atomic); .ele last: the
  # mesh is complete once it is there
  for ext in node face ele; do
    mv "$work/$name.1.$ext" "$out/.$name.$ext.part"
    mv "$out/.$name.$ext.part" "$out/$name.$ext"
  done
  echo "organ_meshes: wrote $out/$name.ele ($(head -1 "$out/$name.node" | cut -d' ' -f1) nodes)"
}

make kidney hubmap_VH_F_kidney_R_outer_cortex_meshfix.off p
make heart hubmap_VH_M_heart_left_ventricle.off p
make prostate hubmap_VH_M_prostate_peripheral_zone_L.off pY
