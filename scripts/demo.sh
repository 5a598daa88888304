#!/usr/bin/env bash
# The main job: generate the paper's cylinder, press it with a rigid sphere (an indentation:
# press, hold, withdraw) on 2 MPI ranks, write the HDF5 series and pictures, print the
# summary. Installs what is missing first.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
source scripts/env.sh
mkdir -p out
./target/release/eprop mesh cylinder -o out/cylinder.msh --overwrite
# --overwrite: the demo makes out/cylinder.h5 anew each time
cp scenarios/cylinder_indent.toml scenarios/cylinder_indent_path.csv out/
mpirun -n 2 ./target/release/eprop run out/cylinder_indent.toml --output out/cylinder.h5 --quiet --overwrite
echo
echo "pictures (the dent at output step 70, the end of the hold):"
py=.venv/bin/python
$py scripts/plot_series.py out/cylinder.h5 --step 70 --out-dir out | sed 's/^/  /'
$py scripts/render.py out/cylinder.h5 -o out/cylinder_energy.png --step 70 2>/dev/null | sed 's/^/  /'
$py scripts/history.py out/cylinder.h5 -o out/cylinder_energy_history.png | sed 's/^/  /'
$py scripts/force_indentation.py out/cylinder.h5 -o out/cylinder_force_indentation.png | sed 's/^/  /'
echo "series: out/cylinder.h5 (open in ParaView 5.12+, or with h5py)"
