#!/usr/bin/env python3
"""Time eprop's explicit substep x <- x + h L x (three components) with PETSc's MatMult.

The operator comes from `eprop export-operator SCENARIO -o A.h5` (CSR, the compact scheme's
L with its diagonal). Run under mpirun for several ranks; prints one JSON line on rank 0.
Needs Debian's python3-petsc4py (apt-get install python3-petsc4py) and python3-h5py.

examples:
  bench_petsc.py A.h5
  mpirun -n 2 python3 bench_petsc.py A.h5 --seconds 3
scripts/bench_petsc.sh runs the whole comparison (eprop and PETSc on 1 and 2 ranks)."""
import argparse
import json
import sys
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("operator", help="HDF5 file written by eprop export-operator")
    ap.add_argument("--seconds", type=float, default=2.0, help="time budget of the measurement (default 2)")
    a = ap.parse_args()
    try:
        import petsc4py
        petsc4py.init([])
        from petsc4py import PETSc
    except ImportError:
        sys.exit("bench_petsc.py: petsc4py is missing; fix: apt-get install python3-petsc4py")
    import h5py
    import numpy as np

    comm = PETSc.COMM_WORLD
    rank, size = comm.getRank(), comm.getSize()
    try:
        f = h5py.File(a.operator, "r")
    except OSError as e:
        sys.exit(f"bench_petsc.py: {a.operator}: cannot open: {e}")
    with f:
        row_ptr = f["row_ptr"]
        n = len(row_ptr) - 1
        h = float(f.attrs["h"])
        lo, hi = rank * n // size, (rank + 1) * n // size
        rp = row_ptr[lo:hi + 1]
        cols = f["col"][rp[0]:rp[-1]].astype(PETSc.IntType)
        vals = f["val"][rp[0]:rp[-1]]
    rp = (rp - rp[0]).astype(PETSc.IntType)
    m = hi - lo
    A = PETSc.Mat().createAIJ(size=((m, n), (m, n)), csr=(rp, cols, vals), comm=comm)
    A.assemble()
    xs = [A.createVecRight() for _ in range(3)]
    y = A.createVecLeft()
    for c, x in enumerate(xs):
        x.setArray(np.sin(np.arange(lo, hi) * (c + 1.0)))

    def substep():
        for x in xs:
            A.mult(x, y)
            x.axpy(h, y)

    for _ in range(3):
        substep()
    comm.barrier()
    t = time.perf_counter()
    for _ in range(5):
        substep()
    t5 = vmax(PETSc, comm, time.perf_counter() - t) / 5
    k = int(min(20000, max(10, a.seconds / max(t5, 1e-9))))
    comm.barrier()
    t = time.perf_counter()
    for _ in range(k):
        substep()
    comm.barrier()
    dt = vmax(PETSc, comm, time.perf_counter() - t)
    nz = int(A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])  # collective: every rank
    if rank == 0:
        print(json.dumps({"nodes": n, "processes": size, "substeps": k, "seconds_per_substep": dt / k,
                          "node_substeps_per_second": n * k / dt, "nonzeros": nz}))
    for o in xs + [y, A]:
        o.destroy()


def vmax(PETSc, comm, x):
    """Largest x over the ranks (PETSc only; no mpi4py needed)."""
    v = PETSc.Vec().createMPI((1, comm.getSize()), comm=comm)
    v.setValue(comm.getRank(), x)
    v.assemble()
    return v.max()[1]


if __name__ == "__main__":
    main()
