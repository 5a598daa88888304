#!/usr/bin/env bash
# The deep halo against one exchange per substep, and both against PETSc, in one run.
# usage: scripts/bench_deep.sh [CELLS...]   (unit boxes of CELLS^3 cells; default 66 99: 300,763
# and 1,000,000 nodes). Env: REPEATS (turns, default 3), PETSC_SECONDS (per PETSc measurement,
# default 4), HALO (halo layers and substeps per fused sweep on two processes, default 4).
# Per box and turn, in this order: PETSc dense-block and 3-MatMult forms on 1 rank, `eprop
# bench` on 1 process (its tuned fused sweep and one substep per sweep, alternating chunks),
# PETSc on 2 ranks, `eprop bench` on 2 processes over a deep halo with sweeps of HALO substeps
# (EPROP_HALO=EPROP_FUSE=HALO; "1/sw" is one substep per sweep on the same processes, what two
# processes run by default), the same with the one-wavefront deep sweep (EPROP_DEEPFRONT=1). Prints node-substeps/s per run and the medians, the ratios
# against PETSc's dense form, the fraction of the triad (measured inside each eprop run) and
# the 2-process speed-up. Needs python3-petsc4py (scripts/bench_petsc.sh installs it).
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
source "$here/scripts/env.sh"
cells=("$@")
[ $# -eq 0 ] && cells=(66 99)
repeats="${REPEATS:-3}"
secs="${PETSC_SECONDS:-4}"
halo="${HALO:-4}"
if [ -z "${PETSC_DIR:-}" ]; then
  for d in /usr/lib/petsc /usr/lib/petscdir/petsc*/x86_64-linux-gnu-real; do
    [ -d "$d/lib/python3/dist-packages/petsc4py" ] && export PETSC_DIR="$d" && break
  done
fi
eprop="$here/target/release/eprop"
[ -x "$eprop" ] || { echo "bench_deep.sh: $eprop not found; fix: cargo build --release" >&2; exit 1; }
/usr/bin/python3 -c "import petsc4py" 2>/dev/null || { echo "bench_deep.sh: petsc4py does not import; fix: scripts/bench_petsc.sh installs python3-petsc4py" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for c in "${cells[@]}"; do
  "$eprop" mesh box --cells "$c,$c,$c" -o "$work/box.msh" >/dev/null
  printf '[mesh]\nfile = "box.msh"\n[[fixed]]\ngroup = "xmin"\n[[load]]\nnearest = [1.0, 0.5, 0.5]\nnormal = 1.0\n[time]\nsteps = 1\n' > "$work/box.toml"
  "$eprop" export-operator "$work/box.toml" -o "$work/A$c.h5" >/dev/null
  rm -f "$work/box.msh"
  for r in $(seq "$repeats"); do
    echo "# $c^3 turn $r: $(uptime | sed 's/.*load average/load average/')" >&2
    mpirun -n 1 /usr/bin/python3 "$here/scripts/bench_petsc.py" "$work/A$c.h5" --seconds "$secs" | tail -1 >> "$work/$c-p1.jsonl"
    "$eprop" bench --cells "$c" --schemes compact --json "$work/e.json" >/dev/null
    /usr/bin/python3 -c "import json,sys; print(json.dumps(json.load(open(sys.argv[1]))[0]))" "$work/e.json" >> "$work/$c-e1.jsonl"
    mpirun -n 2 /usr/bin/python3 "$here/scripts/bench_petsc.py" "$work/A$c.h5" --seconds "$secs" | tail -1 >> "$work/$c-p2.jsonl"
    EPROP_HALO="$halo" EPROP_FUSE="$halo" mpirun -n 2 -x EPROP_HALO -x EPROP_FUSE "$eprop" bench --cells "$c" --schemes compact --json "$work/e.json" >/dev/null
    /usr/bin/python3 -c "import json,sys; print(json.dumps(json.load(open(sys.argv[1]))[0]))" "$work/e.json" >> "$work/$c-deep.jsonl"
    EPROP_DEEPFRONT=1 EPROP_HALO="$halo" EPROP_FUSE="$halo" mpirun -n 2 -x EPROP_DEEPFRONT -x EPROP_HALO -x EPROP_FUSE "$eprop" bench --cells "$c" --schemes compact --json "$work/e.json" >/dev/null
    /usr/bin/python3 -c "import json,sys; print(json.dumps(json.load(open(sys.argv[1]))[0]))" "$work/e.json" >> "$work/$c-front.jsonl"
  done
done
/usr/bin/python3 - "$work" "$halo" "${cells[@]}" <<'PY'
import json, sys
work, halo, cells = sys.argv[1], sys.argv[2], sys.argv[3:]
med = lambda v: sorted(v)[len(v) // 2]
load = lambda f: [json.loads(l) for l in open(f"{work}/{f}.jsonl")]
for c in cells:
    p1, p2, e1, dp, fr2 = (load(f"{c}-{k}") for k in ("p1", "p2", "e1", "deep", "front"))
    print(f"{e1[0]['nodes']:,} nodes (node-substeps/s; sw = substeps per sweep; frac = GB/s / triad of the same run)")
    rows = [("1 eprop (default)", e1, "node_substeps_per_second"), ("1 eprop 1/sweep", e1, "single_node_substeps_per_second"),
            (f"2 eprop halo {halo}, {halo}/sw", dp, "node_substeps_per_second"), (f"2 eprop halo {halo}, 1/sw", dp, "single_node_substeps_per_second"),
            (f"2 eprop front {halo}, {halo}/sw", fr2, "node_substeps_per_second"), (f"2 eprop front {halo}, 1/sw", fr2, "single_node_substeps_per_second")]
    pd = {1: med([x['dense_node_substeps_per_second'] for x in p1]), 2: med([x['dense_node_substeps_per_second'] for x in p2])}
    p3 = {1: med([x['mult3_node_substeps_per_second'] for x in p1]), 2: med([x['mult3_node_substeps_per_second'] for x in p2])}
    print(f"  {'variant':28} {'median':>10} {'runs':>32} {'x dense':>8} {'sw':>3} {'frac':>5} {'halo%':>6} {'triad':>6}")
    for name, e, key in rows:
        n = int(name[0])
        v = [x[key] for x in e]
        fr = [x['bytes_per_node_substep'] * x[key] / 1e9 / x['triad_gb_per_s'] for x in e]
        print(f"  {name:28} {med(v):10.3e} {' '.join(f'{x:.2e}' for x in v):>32} {med(v) / pd[n]:8.2f} "
              f"{med([x['substeps_per_sweep'] for x in e]) if '1/sw' not in name else 1:3d} {med(fr):5.2f} "
              f"{100 * med([x['halo_wait_share'] for x in e]):6.1f} {med([x['triad_gb_per_s'] for x in e]):6.1f}")
    for n, p in ((1, p1), (2, p2)):
        runs = ' '.join('%.2e' % x['dense_node_substeps_per_second'] for x in p)
        print(f"  {n} PETSc dense {pd[n]:10.3e} ({runs}), "
              f"3mult {p3[n]:10.3e}")
    f1 = med([x['node_substeps_per_second'] for x in e1])
    u1 = med([x['single_node_substeps_per_second'] for x in e1])
    fd = med([x['node_substeps_per_second'] for x in dp])
    ud = med([x['single_node_substeps_per_second'] for x in dp])
    print(f"  2 processes over 1: deep fused / 1 default {fd / f1:.2f}, 1/sw / 1/sw {ud / u1:.2f}, "
          f"deep fused / 1 1/sw {fd / u1:.2f}; deep fused / 2 1/sw (same runs) {fd / ud:.2f}")
PY
