#!/usr/bin/env bash
# eprop's compact substep against PETSc on the same operator, 1 and 2 ranks, in one run.
# usage: scripts/bench_petsc.sh [CELLS] [SECONDS] [REPEATS]   (unit box of CELLS^3 cells; default
# 66: 300,763 nodes; SECONDS per PETSc measurement, default 6; REPEATS: PETSc and eprop take
# turns this many times per rank count, medians shown, default 1)
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
repeats="${3:-1}"
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
[model]
reading = "paper"
[[fixed]]
group = "xmin"
[[load]]
nearest = [1.0, 0.5, 0.5]
normal = 1.0
[time]
steps = 1
TOML
"$eprop" export-operator "$work/box.toml" -o "$work/A.h5" >/dev/null
# PETSc and eprop take turns, `repeats` times per rank count; the table shows medians
for r in $(seq "$repeats"); do
  for n in 1 2; do
    mpirun -n "$n" /usr/bin/python3 "$here/scripts/bench_petsc.py" "$work/A.h5" --seconds "$secs" | tail -1 >> "$work/p$n.jsonl"
    if [ "$n" -eq 1 ]; then "$eprop" bench --cells "$cells" --schemes compact --json "$work/e.json" >/dev/null
    else mpirun -n "$n" "$eprop" bench --cells "$cells" --schemes compact --json "$work/e.json" >/dev/null; fi
    /usr/bin/python3 -c "import json,sys; print(json.dumps(json.load(open(sys.argv[1]))[0]))" "$work/e.json" >> "$work/e$n.jsonl"
  done
done
/usr/bin/python3 - "$work" "$repeats" <<'PY'
import json, sys
work, reps = sys.argv[1], int(sys.argv[2])
med = lambda v: sorted(v)[len(v) // 2]
print(f"{'ranks':>6} {'eprop':>12} {'sw':>3} {'eprop 1/sw':>12} {'PETSc dense':>12} {'PETSc 3mult':>12} {'x dense':>8} "
      f"{'x 3mult':>8} {'1/sw xd':>8} {'1/sw x3':>8} {'frac':>6} {'triad':>6}   (medians of {reps})")
for n in (1, 2):
    p = [json.loads(l) for l in open(f"{work}/p{n}.jsonl")]
    e = [json.loads(l) for l in open(f"{work}/e{n}.jsonl")]
    ef, e1 = med([x['node_substeps_per_second'] for x in e]), med([x['single_node_substeps_per_second'] for x in e])
    pd, p3 = med([x['dense_node_substeps_per_second'] for x in p]), med([x['mult3_node_substeps_per_second'] for x in p])
    sw = med([x['substeps_per_sweep'] for x in e])
    frac, triad = med([x['fraction_of_triad'] for x in e]), med([x['triad_gb_per_s'] for x in e])
    print(f"{n:>6} {ef:12.4e} {sw:3d} {e1:12.4e} {pd:12.4e} {p3:12.4e} {ef / pd:8.2f} {ef / p3:8.2f} "
          f"{e1 / pd:8.2f} {e1 / p3:8.2f} {frac:6.2f} {triad:6.1f}")
    for k, (x, y) in enumerate(zip(e, p)):
        print(f"{'':>6} run {k + 1}: eprop {x['node_substeps_per_second']:.3e} ({x['substeps_per_sweep']}/sweep), "
              f"1/sw {x['single_node_substeps_per_second']:.3e}, PETSc dense {y['dense_node_substeps_per_second']:.3e}, "
              f"3mult {y['mult3_node_substeps_per_second']:.3e}, frac {x['fraction_of_triad']:.2f}")
PY
