#!/usr/bin/env bash
# Integrators on a stiff real organ mesh (BENCHMARKS.md, "Integrators"): a 271k-node tetgen
# liver (sofa_liver_main_closed.off, tetgen -pq1.414a2.5, slivers kept) at conductivity 5, where
# euler needs 18,324 substeps per mechanics step. Time per step of every integrator on 1 and 2
# processes (examples/integrators.rs, steps taken in turn) and the relative L2 error of u after
# 10 steps against euler at its own substep.
#   scripts/bench_integrators.sh [OUT_DIR] [SHARED_MESH_DIR]
# Stages: the mesh and the euler reference (10 full euler steps, about 20-30 min on one
# process; both skipped when they exist); the timed runs (euler on 2 steps only); two processes
# against one (no euler). CONDUCTIVITY=1.0 for the 3,665-substep case.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:-$root/target/bench-integrators}"
shared="${2:-$root/../shared/meshes}"
conductivity="${CONDUCTIVITY:-5.0}"
mkdir -p "$out"
cd "$root"
cargo build --release --quiet --example integrators
bin="$root/target/release/examples/integrators"
if [ ! -s "$out/liver.1.ele" ]; then
  cp "$shared/surface/sofa_liver_main_closed.off" "$out/liver.off"
  (cd "$out" && tetgen -pq1.414a2.5 -Q liver.off)
fi
sc="$out/liver_k$conductivity.toml"
cat > "$sc" <<TOML
# 271k-node tetgen liver (mm), held at its left lobe, pressed on the top by a tool
[mesh]
file = "liver.1.ele"
[model]
reading = "paper"
[material]
conductivity = $conductivity
[[fixed]]
halfspace = { point = [45.0, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }
[[load]]
patch = { center = [110.18, 199.95, 129.04], radius = 10.0 }
normal = 400.0
[time]
steps = 10
[output]
fields = ["displacement"]
TOML
ref="$out/euler_u_k$conductivity.bin"
source scripts/env.sh
if [ ! -s "$ref" ]; then
  RAYON_NUM_THREADS=2 "$bin" "$sc" 10 10 "$ref" | tee "$out/reference_k$conductivity.txt"
fi
RAYON_NUM_THREADS=2 "$bin" "$sc" 10 2 "$ref" | tee "$out/np1_k$conductivity.txt"
mpirun -n 2 "$bin" "$sc" 10 2 "$ref" | tee "$out/np2_k$conductivity.txt"
# two processes against one, one thread each: three short runs of each, taken in turn
for rep in 1 2 3; do
  RAYON_NUM_THREADS=1 "$bin" "$sc" 3 0 | sed "s/^/1 process, run $rep: /"
  mpirun -n 2 "$bin" "$sc" 3 0 | sed "s/^/2 processes, run $rep: /"
done | tee "$out/speedup_k$conductivity.txt"
