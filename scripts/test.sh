#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: unit, integration, the multi-rank
# (mpirun -n 2, 3, 4) tests and the post-processing script. Also checks format and lints.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
source scripts/env.sh
cargo fmt --all -- --check
cargo clippy --release --all-targets --quiet -- -D warnings
cargo test --release --workspace 2>&1 | tee /tmp/eprop-test.log
# post-processing: the plotting script on a fresh run
out=$(mktemp -d)
./target/release/eprop mesh cylinder -o "$out/cyl.msh" >/dev/null
sed "s#file = \"cylinder.msh\"#file = \"$out/cyl.msh\"#; s#steps = 100#steps = 10#" scenarios/cylinder.toml > "$out/s.toml"
./target/release/eprop run "$out/s.toml" -q -o "$out/s.h5" >/dev/null
pngs=$(/usr/bin/python3 scripts/plot_series.py "$out/s.h5" --out-dir "$out")
for p in $pngs; do
  [ -s "$p" ] || { echo "plot_series.py wrote no $p"; exit 1; }
done
echo "plot_series.py: ok ($(echo $pngs | wc -w) pictures)"
rm -rf "$out"
passed=$(grep -Eo '^test result: ok\. [0-9]+ passed' /tmp/eprop-test.log | awk '{s += $4} END {print s + 1}')
echo "eprop: $passed passed, 0 failed"
