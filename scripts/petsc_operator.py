"""What the PETSc comparison scripts share (bench_ksp.py, bench_petsc.py): petsc4py started,
and an operator file of `eprop export-operator` opened, each failing with the fix.

example:
  from petsc_operator import import_petsc, open_operator
  PETSc = import_petsc("bench_ksp.py")
  with open_operator("A.h5", "bench_ksp.py") as f: ..."""
import sys


def import_petsc(prog):
    """petsc4py's PETSc, initialised without command-line options."""
    try:
        import petsc4py
        petsc4py.init([])
        from petsc4py import PETSc
    except ImportError:
        sys.exit(f"{prog}: petsc4py is missing; fix: apt-get install python3-petsc4py")
    return PETSc


def open_operator(path, prog):
    """The operator file, opened read-only with h5py."""
    import h5py
    try:
        return h5py.File(path, "r")
    except OSError as e:
        sys.exit(f"{prog}: {path}: cannot open: {e}")
