#!/usr/bin/env bash
# The main job: generate the paper's cylinder, deform it on 2 MPI ranks, write the HDF5
# series and pictures, print the summary. Installs what is missing first.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
source scripts/env.sh
mkdir -p out
./target/release/eprop mesh cylinder -o out/cylinder.msh
cp scenarios/cylinder.toml out/cylinder.toml
# --overwrite: the demo makes out/cylinder.h5 anew each time
mpirun -n 2 ./target/release/eprop run out/cylinder.toml --output out/cylinder.h5 --quiet --overwrite
echo
echo "pictures:"
py=.venv/bin/python
$py scripts/plot_series.py out/cylinder.h5 --out-dir out | sed 's/^/  /'
$py scripts/render.py out/cylinder.h5 -o out/cylinder_energy.png --scale 2 2>/dev/null | sed 's/^/  /'
$py scripts/history.py out/cylinder.h5 -o out/cylinder_energy_history.png | sed 's/^/  /'
$py scripts/force_displacement.py out/cylinder.h5 -o out/cylinder_force_displacement.png | sed 's/^/  /'
echo "series: out/cylinder.h5 (open in ParaView 5.12+, or with h5py)"
