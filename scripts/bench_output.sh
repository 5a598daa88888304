#!/usr/bin/env bash
# The cost of writing output, against the disk: a generated box (default 36^3 cells, 50,653
# nodes), 100 steps with an output step after each, on 1 and 2 processes, beside `dd` writing
# the same bytes to the same directory (one sync at the end, as a run's flushes sync its
# steps), and beside `eprop check`'s prediction. Each case runs --reps times, alternating;
# medians are printed.
#
#   scripts/bench_output.sh [--cells N] [--reps R] [--dir DIR] [--flush SECONDS]
#
# DIR (default: a new directory under ./out) is where the series and dd's file go: put it on
# the disk whose speed matters. --flush sets `[output] flush` (default 1; 0 completes every
# output step in the file, a sync each under MPI).
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
cells=36 reps=5 dir="" flush=1
while [ $# -gt 0 ]; do
    case "$1" in
    --cells) cells="$2"; shift 2 ;;
    --reps) reps="$2"; shift 2 ;;
    --dir) dir="$2"; shift 2 ;;
    --flush) flush="$2"; shift 2 ;;
    -h | --help) sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench_output.sh: unknown argument $1; fix: see --help" >&2; exit 2 ;;
    esac
done
source "$here/scripts/env.sh"
eprop="$here/target/release/eprop"
[ -x "$eprop" ] || (cd "$here" && cargo build --release -q)
if [ -z "$dir" ]; then
    mkdir -p "$here/out"
    dir="$(mktemp -d "$here/out/bench_output.XXXX")"
fi
mkdir -p "$dir"
cd "$dir"
"$eprop" mesh box --size 0.1,0.1,0.1 --cells "$cells,$cells,$cells" --output box.msh --overwrite >/dev/null
# one explicit substep per step: the steps cost little beside their output
dt=$(python3 -c "print(9e-6 * (36 / $cells) ** 2)")
cat >box.toml <<EOF
[mesh]
file = "box.msh"
unit = "m"
[[fixed]]
group = "zmin"
[[load]]
patch = { center = [0.05, 0.05, 0.1], radius = 0.02 }
normal = 0.5
[time]
steps = 100
dt = $dt
[output]
file = "box.h5"
every = 1
flush = $flush
EOF
predicted=$("$eprop" check box.toml --json | python3 -c "import json,sys; print(json.load(sys.stdin)['output_seconds'])")
results=results.txt
: >"$results"
for _ in $(seq "$reps"); do
    for ranks in 1 2; do
        rm -f box.h5
        if [ "$ranks" = 1 ]; then
            json=$("$eprop" run box.toml -q --json)
        else
            json=$(RAYON_NUM_THREADS=1 mpirun -n 2 "$eprop" run box.toml -q --json)
        fi
        echo "$json" | python3 -c "import json,sys; d=json.load(sys.stdin); print('eprop$ranks', d['output_seconds'], d['output_steps'])" >>"$results"
    done
    bytes=$(stat -c %s box.h5)
    step_bytes=$((bytes / 101))
    t0=$(date +%s.%N)
    dd if=/dev/zero of=dd.bin bs="$step_bytes" count=101 conv=fdatasync status=none
    t1=$(date +%s.%N)
    echo "dd $(python3 -c "print($t1 - $t0)") 101" >>"$results"
    rm -f dd.bin
done
rm -f box.h5
python3 - "$results" "$predicted" "$(stat -c %s box.msh)" "$cells" <<'EOF'
import sys, statistics
rows = [l.split() for l in open(sys.argv[1])]
predicted = float(sys.argv[2])
cells = int(sys.argv[4])
nodes = (cells + 1) ** 3
med = {}
for name in ("eprop1", "eprop2", "dd"):
    secs = [float(r[1]) for r in rows if r[0] == name]
    med[name] = statistics.median(secs)
steps = 101
print(f"box {cells}^3 cells ({nodes} nodes), {steps} output steps, medians of {len(rows) // 3} runs each")
print(f"{'writer':<28}{'s in all':>10}{'ms per step':>13}{'x dd':>8}")
for name, label in (("eprop1", "eprop, 1 process"), ("eprop2", "eprop, 2 processes"), ("dd", "dd, the same bytes, 1 sync")):
    print(f"{label:<28}{med[name]:>10.3f}{1e3 * med[name] / steps:>13.2f}{med[name] / med['dd']:>8.2f}")
print(f"2 processes / 1 process: {med['eprop2'] / med['eprop1']:.2f}")
print(f"eprop check predicted {predicted:.3f} s: {med['eprop1'] / predicted:.2f}x of it on 1 process, {med['eprop2'] / predicted:.2f}x on 2")
EOF
