#!/usr/bin/env python3
"""Time PETSc KSP CG on the implicit integrator's systems, beside eprop's own solves.

The operator comes from `eprop export-operator SCENARIO -o A.h5` (L, the free nodes' control
volumes vol, the mechanics step dt and TR-BDF2's theta). On the free rows it forms
A = V - theta dt V L, TR-BDF2's matrix (both stages share it), and times what one eprop step
solves: two stages, three components each, solved one by one (6 KSP solves from x = 0,
right-hand sides V z with z pseudo-random), rtol 1e-8 (eprop's default tolerance, on the
preconditioned residual as eprop's), setup (PCSetUp) excluded. Preconditioners: jacobi, gamg,
hypre (BoomerAMG), each with PETSc's defaults. Run under mpirun for several ranks; prints one
JSON line per preconditioner on rank 0: iterations per solve and seconds per step (median of
the repetitions). Needs Debian's python3-petsc4py and python3-h5py.

examples:
  bench_ksp.py A.h5
  mpirun -n 2 python3 bench_ksp.py A.h5 --repeats 5
scripts/bench_implicit.sh runs the whole comparison (eprop and PETSc on 1 and 2 ranks)."""
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
    ap.add_argument("--pc", default="jacobi,gamg,hypre", help="preconditioners, comma-separated (default jacobi,gamg,hypre)")
    ap.add_argument("--repeats", type=int, default=3, help="steps timed per preconditioner (default 3)")
    ap.add_argument("--rtol", type=float, default=1e-8, help="relative tolerance (default 1e-8)")
    a = ap.parse_args()
    PETSc = import_petsc("bench_ksp.py")
    import numpy as np

    comm = PETSc.COMM_WORLD
    rank, size = comm.getRank(), comm.getSize()
    with open_operator(a.operator, "bench_ksp.py") as f:
        if "vol" not in f:
            sys.exit(f"bench_ksp.py: {a.operator} has no vol; fix: write it again with this eprop's export-operator")
        row_ptr = f["row_ptr"][:]
        vol = f["vol"][:]
        tt = float(f.attrs["theta"]) * float(f.attrs["dt"])
        free = np.flatnonzero(vol > 0)
        nf = len(free)
        lo, hi = rank * nf // size, (rank + 1) * nf // size
        mine = free[lo:hi]
        new = -np.ones(len(vol), dtype=np.int64)
        new[free] = np.arange(nf)
        col_all = f["col"]
        val_all = f["val"]
        s, e = row_ptr[mine[0]] if len(mine) else 0, row_ptr[mine[-1] + 1] if len(mine) else 0
        cols = col_all[s:e]
        vals = val_all[s:e]
    rp, cc, vv = [0], [], []
    for g in mine:
        a0, a1 = row_ptr[g] - s, row_ptr[g + 1] - s
        c = cols[a0:a1]
        v = vals[a0:a1] * (-tt * vol[g])
        v[c == g] += vol[g]
        keep = new[c] >= 0
        cc.append(new[c[keep]])
        vv.append(v[keep])
        rp.append(rp[-1] + int(keep.sum()))
    cc = np.concatenate(cc).astype(PETSc.IntType) if cc else np.zeros(0, PETSc.IntType)
    vv = np.concatenate(vv) if vv else np.zeros(0)
    m = hi - lo
    A = PETSc.Mat().createAIJ(size=((m, nf), (m, nf)), csr=(np.array(rp, dtype=PETSc.IntType), cc, vv), comm=comm)
    A.assemble()
    rhs = []
    for c in range(6):
        b = A.createVecLeft()
        z = np.sin(np.arange(lo, hi) * (c + 1.3) + 0.7)
        b.setArray(vol[mine] * z)
        rhs.append(b)
    x = A.createVecRight()
    for pc in a.pc.split(","):
        ksp = PETSc.KSP().create(comm)
        ksp.setOperators(A)
        ksp.setType("cg")
        ksp.getPC().setType(pc)
        if pc == "hypre":
            ksp.getPC().setHYPREType("boomeramg")
        ksp.setTolerances(rtol=a.rtol, max_it=5000)
        ksp.setFromOptions()
        t = time.perf_counter()
        ksp.setUp()
        setup = time.perf_counter() - t
        times, its = [], []
        for _ in range(a.repeats):
            comm.barrier()
            t = time.perf_counter()
            for b in rhs:
                x.set(0.0)
                ksp.solve(b, x)
                its.append(ksp.getIterationNumber())
            comm.barrier()
            times.append(time.perf_counter() - t)
        times.sort()
        if rank == 0:
            print(json.dumps({"pc": pc, "rows": nf, "processes": size, "iterations_per_solve": sum(its) / len(its),
                              "s_per_step": times[len(times) // 2], "setup_s": setup}), flush=True)
        ksp.destroy()


if __name__ == "__main__":
    main()
