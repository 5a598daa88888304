#!/bin/bash
# The scale study of docs/scaling.md: peak resident memory and setup time of every rank of
# `mpirun -n P eprop run` started from a .vtkhdf mesh (every rank reads its slab), on boxes of
# several sizes, at several rank counts.
#
#   scripts/scale_study.sh [OUT_DIR]          # default out/scale
#   CELLS="62 99 125" RANKS="1 2 4 8" EPROP=target/release/eprop scripts/scale_study.sh
#
# CELLS: cells per axis of each box (`eprop mesh box --cells N,N,N --kind tet`: (N+1)^3 nodes,
# 6 N^3 tetrahedra; 62 -> 250,047 nodes, 99 -> 1,000,000, 125 -> 2,000,376). RANKS: process
# counts (more than the cores are oversubscribed: memory and counts stay meaningful, times do
# not). The run: paper reading, euler, one step of one substep, fixed bottom (halfspace), a
# `nearest` load, output at the start and the end.
#
# Per run, OUT_DIR/N-P/ holds each rank's stderr (`eprop -vv`: resident and peak memory after each
# setup phase, with the time since the start) and its /usr/bin/time output; OUT_DIR/results.tsv has
# one line per rank: cells, nodes, ranks, rank, peak MiB (VmHWM), resident MiB after the slab
# read (the whole mesh on one process), the local mesh, the plan, the geometry, the operator, the static output and the first
# output step, the setup seconds (to "geometry and operator built") and the wall seconds;
# then the seconds since the start at which the mesh (the slab) was read, the graph split, the
# cells moved to their owners and the part (plan, scenario) made.
# OUT_DIR/convert.tsv the peak MiB and seconds of `eprop convert` (one process, the whole mesh).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=${1:-out/scale}
eprop=${EPROP:-$here/../target/release/eprop}
cells=${CELLS:-"62 99"}
ranks=${RANKS:-"1 2 4 8"}
if [ ! -x "$eprop" ]; then
  echo "scale_study.sh: no eprop binary at $eprop; fix: cargo build --release, or EPROP=/path/to/eprop" >&2
  exit 1
fi
if [ ! -x /usr/bin/time ]; then
  echo "scale_study.sh: /usr/bin/time is missing; fix: apt-get install time" >&2
  exit 1
fi
eprop=$(cd "$(dirname "$eprop")" && pwd)/$(basename "$eprop")
mkdir -p "$out"
out=$(cd "$out" && pwd)
export RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-1}
cores=$(nproc)
results=$out/results.tsv
if [ ! -f "$out/convert.tsv" ]; then printf 'cells\tnodes\tconvert_peak_MiB\tconvert_s\n' >"$out/convert.tsv"; fi
printf 'cells\tnodes\tranks\trank\tpeak_MiB\tslab_MiB\tlocal_mesh_MiB\tplan_MiB\tgeometry_MiB\toperator_MiB\tstatic_output_MiB\tfirst_step_MiB\tsetup_s\twall_s\tread_at_s\tsplit_at_s\tmoved_at_s\tpart_at_s\n' >"$results"

# the resident MiB of the first "memory after WHAT" line of a log
phase() {
  sed -n "s/.*memory after $2: \([0-9.]*\) MiB resident.*/\1/p" "$1" | head -n 1
}
# the seconds since the start of the first line of a log that holds WHAT
at() {
  sed -n "s/^ *\([0-9.]*\)s .*$2.*/\1/p" "$1" | head -n 1
}

for n in $cells; do
  mesh=$out/box$n.vtkhdf
  if [ ! -f "$mesh" ]; then
    /usr/bin/time -f '%M %e' -o "$out/box$n.time" "$eprop" mesh box --cells "$n,$n,$n" --kind tet -o "$out/box$n.msh"
    /usr/bin/time -f '%M %e' -o "$out/convert$n.time" "$eprop" convert "$out/box$n.msh" "$mesh"
    read -r kib wall <"$out/convert$n.time"
    printf '%s\t%s\t%.0f\t%s\n' "$n" "$(((n + 1) * (n + 1) * (n + 1)))" "$(echo "$kib / 1024" | bc -l)" "$wall" >>"$out/convert.tsv"
    rm -f "$out/box$n.msh"
  fi
  nodes=$(((n + 1) * (n + 1) * (n + 1)))
  scenario=$out/box$n.toml
  cat >"$scenario" <<EOF
[mesh]
file = "box$n.vtkhdf"
[model]
reading = "paper"
integrator = "euler"
[[fixed]]
halfspace = { point = [0, 0, 0.01], normal = [0, 0, -1] }
[[load]]
nearest = [0.5, 0.5, 1.0]
normal = 0.05
[time]
steps = 1
dt = 1e-4
[output]
every = 1
EOF
  for p in $ranks; do
    d=$out/$n-$p
    rm -rf "$d"
    mkdir -p "$d"
    over=()
    if [ "$p" -gt "$cores" ]; then over=(--oversubscribe); fi
    # each rank: its own stderr and its own /usr/bin/time record
    mpirun -n "$p" "${over[@]}" sh -c "exec /usr/bin/time -f '%M %e' -o '$d/time.'\$OMPI_COMM_WORLD_RANK '$eprop' -vv run '$scenario' -o '$d/run.h5' 2>'$d/log.'\$OMPI_COMM_WORLD_RANK" >"$d/summary.txt"
    for ((r = 0; r < p; r++)); do
      log=$d/log.$r
      read -r kib wall <"$d/time.$r"
      setup=$(sed -n 's/^ *\([0-9.]*\)s .*geometry and operator built.*/\1/p' "$log" | head -n 1)
      printf '%s\t%s\t%s\t%s\t%.0f\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%.1f\t%s\t%s\t%s\t%s\t%s\n' "$n" "$nodes" "$p" "$r" \
        "$(echo "$kib / 1024" | bc -l)" \
        "$(phase "$log" 'reading the slab of the mesh')$(phase "$log" 'reading the scenario and mesh')" \
        "$(phase "$log" 'the local mesh from the slabs')" \
        "$(phase "$log" 'the local mesh and plan')" \
        "$(phase "$log" 'the dual geometry')" \
        "$(phase "$log" 'the operator')" \
        "$(phase "$log" 'the static output')" \
        "$(phase "$log" 'the first output step')" \
        "$setup" "$wall" \
        "$(at "$log" 'memory after reading')" \
        "$(at "$log" 'nodes split into')" \
        "$(at "$log" 'memory after the local mesh from the slabs')" \
        "$(at "$log" 'part received')" >>"$results"
    done
    tail -n "$p" "$results"
  done
done
echo "scale_study.sh: $results"
