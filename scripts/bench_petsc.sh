#!/usr/bin/env bash
# eprop's compact substep against PETSc MatMult on the same operator, 1 and 2 ranks.
# usage: scripts/bench_petsc.sh [CELLS]   (unit box of CELLS^3 cells; default 66: 300,763 nodes)
# Needs python3-petsc4py (apt-get install python3-petsc4py); prints a table of both and the ratio.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
source "$here/scripts/env.sh"
# Debian's petsc4py finds PETSc through PETSC_DIR when the -dev alternative is not installed
if [ -z "${PETSC_DIR:-}" ]; then
  for d in /usr/lib/petsc /usr/lib/petscdir/petsc*/x86_64-linux-gnu-real; do
    [ -d "$d/lib/python3/dist-packages/petsc4py" ] && export PETSC_DIR="$d" && break
  done
fi
cells="${1:-66}"
eprop="$here/target/release/eprop"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
/usr/bin/python3 -c "import petsc4py" 2>/dev/null || { echo "bench_petsc.sh: petsc4py is missing; fix: apt-get install python3-petsc4py" >&2; exit 1; }
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
printf "%6s %14s %14s %8s\n" ranks "eprop n-sub/s" "PETSc n-sub/s" ratio
for n in 1 2; do
  p=$(mpirun -n "$n" /usr/bin/python3 "$here/scripts/bench_petsc.py" "$work/A.h5" | tail -1)
  if [ "$n" -eq 1 ]; then "$eprop" bench --cells "$cells" --schemes compact --json "$work/e.json" >/dev/null
  else mpirun -n "$n" "$eprop" bench --cells "$cells" --schemes compact --json "$work/e.json" >/dev/null; fi
  /usr/bin/python3 - "$p" "$work/e.json" "$n" <<'PY'
import json, sys
p = json.loads(sys.argv[1]); e = json.load(open(sys.argv[2]))[0]
print(f"{sys.argv[3]:>6} {e['node_substeps_per_second']:14.4e} {p['node_substeps_per_second']:14.4e} {e['node_substeps_per_second'] / p['node_substeps_per_second']:8.2f}")
PY
done
