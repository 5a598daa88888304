#!/usr/bin/env python3
"""Time eprop's explicit substep X <- X + h L X (X: three components per node) with PETSc.

The operator comes from `eprop export-operator SCENARIO -o A.h5` (CSR, the compact scheme's
L with its diagonal). Two formulations, timed in alternating bursts in one run:
  dense  one scalar operator on an n x 3 dense block: A.matMult(X, Y) (MatMatMult, AIJ x
         dense: the matrix is read once per substep), then X.axpy(h, Y) -- what a PETSc user
         applying one operator to a 3-component field writes. MAIJ (MatCreateMAIJ) would be the
         other such form; petsc4py 3.18 has no binding for it.
  3mult  three MatMult + VecAXPY, one per component (the matrix read three times).
Run under mpirun for several ranks; prints one JSON line on rank 0 (node-substeps/s, median of
the bursts, per form). Needs Debian's python3-petsc4py and python3-h5py.

examples:
  bench_petsc.py A.h5
  mpirun -n 2 python3 bench_petsc.py A.h5 --seconds 3
scripts/bench_petsc.sh runs the whole comparison (eprop and PETSc on 1 and 2 ranks)."""
import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from petsc_operator import import_petsc, open_operator  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("operator", help="HDF5 file written by eprop export-operator")
    ap.add_argument("--seconds", type=float, default=6.0, help="time budget of the measurement (default 6)")
    ap.add_argument("--order", choices=["file", "rcm"], default="file",
                    help="row order: the operator file's (the mesh's node order), or PETSc's reverse "
                         "Cuthill-McKee (MatGetOrdering, one process only), as a careful PETSc user "
                         "reorders a mesh whose node order has poor locality (default file)")
    a = ap.parse_args()
    PETSc = import_petsc("bench_petsc.py")
    import numpy as np

    comm = PETSc.COMM_WORLD
    rank, size = comm.getRank(), comm.getSize()
    with open_operator(a.operator, "bench_petsc.py") as f:
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
    if a.order == "rcm":
        if size > 1:
            sys.exit("bench_petsc.py: --order rcm runs on one process (MatGetOrdering is sequential); fix: drop it under mpirun")
        rperm, cperm = A.getOrdering("rcm")
        B = A.permute(rperm, cperm)
        A.destroy()
        A = B
    # dense form: X and Y are m x 3 local blocks (column-major) of n x 3 matrices
    X = PETSc.Mat().createDense(size=((m, n), (None, 3)), comm=comm)
    X.setUp()
    arr = X.getDenseArray()
    for c in range(3):
        arr[:, c] = np.sin(np.arange(lo, hi) * (c + 1.0))
    X.assemble()
    Y = A.matMult(X)  # symbolic and numeric once; later calls reuse Y
    # three-MatMult form
    xs = [A.createVecRight() for _ in range(3)]
    y = A.createVecLeft()
    for c, x in enumerate(xs):
        x.setArray(np.sin(np.arange(lo, hi) * (c + 1.0)))

    def dense():
        A.matMult(X, Y)
        X.axpy(h, Y)

    def mult3():
        for x in xs:
            A.mult(x, y)
            x.axpy(h, y)

    forms = {"dense": dense, "3mult": mult3}
    reps = {}
    for name, f in forms.items():
        for _ in range(3):
            f()
        comm.barrier()
        t = time.perf_counter()
        for _ in range(5):
            f()
        t5 = vmax(PETSc, comm, time.perf_counter() - t) / 5
        # bursts of about 0.3 s; the budget split over the forms and 8 rounds
        reps[name] = int(min(20000, max(3, 0.3 / max(t5, 1e-9))))
    rounds = max(3, int(a.seconds / (0.3 * len(forms))))
    rates = {name: [] for name in forms}
    for _ in range(rounds):
        for name, f in forms.items():
            comm.barrier()
            t = time.perf_counter()
            for _ in range(reps[name]):
                f()
            comm.barrier()
            dt = vmax(PETSc, comm, time.perf_counter() - t)
            rates[name].append(n * reps[name] / dt)
    nz = int(A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])  # collective: every rank
    if rank == 0:
        med = {k: sorted(v)[len(v) // 2] for k, v in rates.items()}
        print(json.dumps({"nodes": n, "processes": size, "order": a.order, "rounds": rounds, "nonzeros": nz,
                          "node_substeps_per_second": med["dense"],
                          "dense_node_substeps_per_second": med["dense"],
                          "mult3_node_substeps_per_second": med["3mult"]}))
    for o in xs + [y, X, Y, A]:
        o.destroy()


def vmax(PETSc, comm, x):
    """Largest x over the ranks (PETSc only; no mpi4py needed)."""
    v = PETSc.Vec().createMPI((1, comm.getSize()), comm=comm)
    v.setValue(comm.getRank(), x)
    v.assemble()
    return v.max()[1]


if __name__ == "__main__":
    main()
