#!/usr/bin/env bash
# Batch job: run a scenario on N MPI ranks (default 2).
#   scripts/run_mpi.sh SCENARIO [N] [extra eprop run options]
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
scenario=${1:?usage: run_mpi.sh SCENARIO [N] [eprop run options]}
n=${2:-2}
shift $(( $# >= 2 ? 2 : 1 ))
source "$here/scripts/env.sh"
exec mpirun -n "$n" "$here/target/release/eprop" run "$scenario" --quiet "$@"
