#!/usr/bin/env bash
# Batch job: run a scenario on N MPI ranks (default 2).
#   scripts/run_mpi.sh SCENARIO [N] [extra eprop run options]
# The binary: $EPROP if set, else `eprop` on PATH, else this checkout's target/release/eprop.
# mpirun gets --oversubscribe only when N exceeds the cores of this machine; MPIRUN_OPTS adds
# options (e.g. MPIRUN_OPTS="--hostfile hosts"); RAYON_NUM_THREADS defaults to 1 per rank.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
scenario=${1:?usage: run_mpi.sh SCENARIO [N] [eprop run options]}
n=${2:-2}
shift $(( $# >= 2 ? 2 : 1 ))
case "$n" in
  '' | *[!0-9]* | 0) echo "run_mpi.sh: N = '$n' is not a positive number of ranks; fix: scripts/run_mpi.sh SCENARIO 4" >&2; exit 2 ;;
esac
eprop=${EPROP:-$(command -v eprop || true)}
[ -n "$eprop" ] || eprop="$here/target/release/eprop"
if [ ! -x "$eprop" ]; then
  echo "run_mpi.sh: no eprop binary at $eprop; fix: cargo build --release (or set EPROP=/path/to/eprop)" >&2
  exit 1
fi
opts=()
cores=$(nproc 2>/dev/null || echo 1)
[ "$n" -gt "$cores" ] && opts+=(--oversubscribe)
# OpenMPI run as root (a container) needs consent
if [ "$(id -u)" -eq 0 ]; then
  export OMPI_ALLOW_RUN_AS_ROOT=${OMPI_ALLOW_RUN_AS_ROOT:-1} OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=${OMPI_ALLOW_RUN_AS_ROOT_CONFIRM:-1}
fi
export RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-1}
# shellcheck disable=SC2086  # a list of options
exec mpirun -n "$n" "${opts[@]}" ${MPIRUN_OPTS:-} "$eprop" run "$scenario" --quiet "$@"
