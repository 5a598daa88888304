#!/usr/bin/env bash
# eprop's compact substep against PETSc on the same operator, 1 and 2 ranks, in one run.
# usage: scripts/bench_petsc.sh [CELLS] [SECONDS]   (unit box of CELLS^3 cells; default 66: 300,763
# nodes; SECONDS per PETSc measurement, default 6)
# PETSc forms (scripts/bench_petsc.py): "dense" = A.matMult(X, Y) on an n x 3 dense block (the
# matrix read once per substep: the strongest form petsc4py 3.18 reaches), "3mult" = three
# MatMult, one per component. eprop: `eprop bench`, its substep as the Euler stepper runs it
# ("sw" substeps per fused sweep) and with one substep per sweep ("1/sw"). Installs Debian's
# python3-petsc4py when it is missing (not a test dependency). Prints one table: node-substeps/s,
# eprop / PETSc ratios, and eprop's effective bandwidth (bytes of a one-substep CSR sweep / time
# per substep) as a fraction of the triad measured in the same eprop run.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
source "$here/scripts/env.sh"
cells="${1:-66}"
secs="${2:-6}"
if ! dpkg-query -W -f='${Status}' python3-petsc4py 2>/dev/null | grep -q "install ok installed"; then
  echo "bench_petsc.sh: installing python3-petsc4py (PETSc 3.18)" >&2
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-petsc4py >/dev/null
fi
# Debian's petsc4py finds PETSc through PETSC_DIR when the -dev alternative is not installed
if [ -z "${PETSC_DIR:-}" ]; then
  for d in /usr/lib/petsc /usr/lib/petscdir/petsc*/x86_64-linux-gnu-real; do
    [ -d "$d/lib/python3/dist-packages/petsc4py" ] && export PETSC_DIR="$d" && break
  done
fi
eprop="$here/target/release/eprop"
[ -x "$eprop" ] || { echo "bench_petsc.sh: $eprop not found; fix: cargo build --release" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
/usr/bin/python3 -c "import petsc4py" 2>/dev/null || { echo "bench_petsc.sh: petsc4py does not import (PETSC_DIR=${PETSC_DIR:-}); fix: apt-get install python3-petsc4py" >&2; exit 1; }
"$eprop" mesh box --cells "$cells,$cells,$cells" -o "$work/box.msh" >/dev/null
cat > "$work/box.toml" <<TOML
[mesh]
file = "box.msh"
[[fixed]]
group = "xmin"
[[load]]
nearest = [1.0, 0.5, 0.5]
normal = 1.0
[time]
steps = 1
TOML
"$eprop" export-operator "$work/box.toml" -o "$work/A.h5" >/dev/null
printf "%6s %12s %3s %12s %12s %12s %8s %8s %8s %8s %6s %6s\n" ranks "eprop" "sw" "eprop 1/sw" "PETSc dense" "PETSc 3mult" \
  "x dense" "x 3mult" "1/sw xd" "1/sw x3" "frac" "triad"
for n in 1 2; do
  p=$(mpirun -n "$n" /usr/bin/python3 "$here/scripts/bench_petsc.py" "$work/A.h5" --seconds "$secs" | tail -1)
  if [ "$n" -eq 1 ]; then "$eprop" bench --cells "$cells" --schemes compact --json "$work/e.json" >/dev/null
  else mpirun -n "$n" "$eprop" bench --cells "$cells" --schemes compact --json "$work/e.json" >/dev/null; fi
  /usr/bin/python3 - "$p" "$work/e.json" "$n" <<'PY'
import json, sys
p = json.loads(sys.argv[1]); e = json.load(open(sys.argv[2]))[0]
ef, e1 = e['node_substeps_per_second'], e['single_node_substeps_per_second']
pd, p3 = p['dense_node_substeps_per_second'], p['mult3_node_substeps_per_second']
print(f"{sys.argv[3]:>6} {ef:12.4e} {e['substeps_per_sweep']:3d} {e1:12.4e} {pd:12.4e} {p3:12.4e} {ef / pd:8.2f} {ef / p3:8.2f} "
      f"{e1 / pd:8.2f} {e1 / p3:8.2f} {e['fraction_of_triad']:6.2f} {e['triad_gb_per_s']:6.1f}")
PY
done
