#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: unit, integration, the multi-rank
# (mpirun -n 2, 3, 4) tests and the post-processing script. Also checks format and lints.
# Prints the real counts of passed, failed, ignored and skipped tests (a skipped test did not
# test what it is for: a tool or the shared data was missing; the reasons are listed), and
# exits non-zero when a test failed. With EPROP_REQUIRE_ALL=1 (CI) a skip is a failure.
set -euo pipefail
cd "$(dirname "$0")/.."
# A full disk shows up as a linker killed by SIGBUS ("ld terminated with signal 7 [Bus error]")
# or as tests failing to write: say so first. The build and the tests need about 5 GiB.
free_kib() { df -Pk "${1:-.}" | awk 'NR == 2 {print $4}'; }
if [ "$(free_kib .)" -lt $((5 * 1024 * 1024)) ]; then
  echo "eprop tests: warning: only $(($(free_kib .) / 1024)) MiB free on $(df -P . | awk 'NR == 2 {print $6}');" \
    "the build and the tests need about 5 GiB (a linker's 'Bus error' means the disk filled)" >&2
fi
scripts/setup.sh
source scripts/env.sh
cargo fmt --all -- --check
cargo clippy --release --workspace --all-targets --quiet -- -D warnings
mkdir -p target/tmp
log=target/tmp/eprop-test.log
skips=target/tmp/eprop-skipped.log
rm -f "$skips"
# The tests open series in their own process (to damage or inspect them) while other tests of
# the same binary start eprop processes: HDF5 opens files without close-on-exec, so a process
# started at that moment inherits the open file and its HDF5 lock, and an eprop run on that
# file fails with "unable to lock file" for as long as that process lives. eprop claims its
# files with its own lock files (README, "Safety"), so the tests do without HDF5's.
export HDF5_USE_FILE_LOCKING=FALSE
set +e
cargo test --release --workspace --no-fail-fast 2>&1 | tee "$log"
status=${PIPESTATUS[0]}
set -e
# one "test result:" line per test binary: "ok. 12 passed; 0 failed; 1 ignored; ..."
# (no such line, as when the build failed, counts 0: grep's "no match" must not end the script)
count() {
  { grep -Eo "^test result: [A-Za-z]+\. .*" "$log" || true; } | { grep -Eo "[0-9]+ $1" || true; } |
    awk '{s += $1} END {print s + 0}'
}
passed=$(count passed)
failed=$(count failed)
ignored=$(count ignored)
skipped=0
[ -f "$skips" ] && skipped=$(wc -l < "$skips")
echo "eprop tests: $passed passed, $failed failed, $ignored ignored, $skipped skipped"
if [ "$skipped" -gt 0 ]; then
  sed 's/^/  skipped: /' "$skips"
fi
if [ "$status" -ne 0 ] || [ "$failed" -ne 0 ]; then
  echo "eprop tests: FAILED (cargo test exited with status $status;" \
    "$(($(free_kib .) / 1024)) MiB free on the disk of target/)"
  exit 1
fi
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
echo "eprop: all $passed tests passed ($ignored ignored, $skipped skipped) and plot_series.py works"
