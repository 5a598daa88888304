#!/usr/bin/env python3
"""The implicit integrator's solves on unit boxes, eprop beside PETSc KSP CG.

For each box of N^3 cells (`eprop mesh box --kind tet`; fixed on x = 0, a patch load on
x = 1, conductivity 0.05, dt automatic: the boxes of issue 24), on 1 and 2 processes:
  - eprop `run` with [model] integrator = "implicit" and each preconditioner: iterations per
    solve and seconds per step from the log (`-vvv`: a line per step and per solve pair;
    steps 2 to S, the mechanics included, and their median, the step past a transient, no output written, setup excluded); with the
    default --accuracy inf one TR-BDF2 step per mechanics step at solver tolerance 1e-8, as
    PETSc's solves below; with an accuracy (1e-3, the run's default) the error control takes
    as many TR-BDF2 steps as it needs, counted in the table;
  - `eprop export-operator`, then scripts/bench_ksp.py: PETSc CG with jacobi, gamg, hypre on
    the same matrix A = V - theta dt W, three components one by one, setup excluded.
Prints a Markdown table. Needs mpirun, and python3-petsc4py / python3-h5py for PETSc
(skipped with --no-petsc).

examples:
  scripts/bench_implicit.py --cells 30,50,70
  scripts/bench_implicit.py --cells 30 --pre multigrid,jacobi --no-petsc"""
import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import json

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(cmd, env=None, both=False):
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        sys.exit(f"bench_implicit.py: {' '.join(cmd)} failed:\n{p.stderr}")
    return (p.stdout, p.stderr) if both else p.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", default="30,50,70", help="box sizes N (N^3 cells), comma-separated")
    ap.add_argument("--procs", default="1,2", help="process counts (default 1,2)")
    ap.add_argument("--pre", default="multigrid,jacobi", help="eprop preconditioners (default multigrid,jacobi)")
    ap.add_argument("--steps", type=int, default=6, help="eprop steps per run (default 6)")
    ap.add_argument("--no-petsc", action="store_true", help="eprop only")
    ap.add_argument("--petsc-rtol", default="1e-8", help="PETSc's relative tolerances, comma-separated (default 1e-8, eprop's without error control)")
    ap.add_argument("--petsc-pc", default="jacobi,gamg,hypre", help="PETSc's preconditioners (default jacobi,gamg,hypre)")
    ap.add_argument("--accuracy", default="inf", help="eprop's [integrator] accuracy (default inf: one TR-BDF2 step per step, no error control)")
    a = ap.parse_args()
    eprop = os.path.join(HERE, "target", "release", "eprop")
    if not os.access(eprop, os.X_OK):
        sys.exit(f"bench_implicit.py: {eprop} not found; fix: cargo build --release")
    env = dict(os.environ, RAYON_NUM_THREADS="1", OMP_NUM_THREADS="1")
    if "PETSC_DIR" not in env:
        # Debian's petsc4py finds PETSc through PETSC_DIR when the -dev alternative is missing
        import glob
        for d in ["/usr/lib/petsc"] + sorted(glob.glob("/usr/lib/petscdir/petsc*/x86_64-linux-gnu-real")):
            if os.path.isdir(os.path.join(d, "lib", "python3", "dist-packages", "petsc4py")):
                env["PETSC_DIR"] = d
                break
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for n in [int(c) for c in a.cells.split(",")]:
            mesh = os.path.join(work, f"box{n}.msh")
            run([eprop, "mesh", "box", "--size", "1,1,1", "--cells", f"{n},{n},{n}", "--kind", "tet", "-o", mesh])
            for pre in a.pre.split(","):
                sc = os.path.join(work, f"box{n}_{pre}.toml")
                with open(sc, "w") as f:
                    f.write(f"""[mesh]
file = "box{n}.msh"
[material]
conductivity = 0.05
[model]
reading = "paper"
integrator = "implicit"
[integrator]
preconditioner = "{pre}"
accuracy = {a.accuracy}
[[fixed]]
group = "xmin"
[[load]]
patch = {{ center = [1.0, 0.5, 0.5], radius = 0.2 }}
normal = 1.0
[time]
steps = {a.steps}
[output]
every = 1000
""")
                for p in [int(x) for x in a.procs.split(",")]:
                    out = os.path.join(work, "o.h5")
                    cmd = [eprop, "-vvv", "run", sc, "-o", out, "--overwrite"]
                    if p > 1:
                        cmd = ["mpirun", "--oversubscribe", "-n", str(p)] + cmd
                    text, log = run(cmd, env, both=True)
                    nodes = re.search(r"\((\d+) nodes", text)
                    # rank 0's (the first) line of each step: its end (uptime) and its TR-BDF2 steps
                    steps = {}
                    for m in re.finditer(r"([\d.]+)s\s+DEBUG implicit step (\d+): (\d+) TR-BDF2 steps, (\d+) rejected", log):
                        steps.setdefault(int(m.group(2)), (float(m.group(1)), int(m.group(3)) + int(m.group(4))))
                    if not steps:
                        # without error control: one TR-BDF2 step per step, a line per solve pair
                        for m in re.finditer(r"([\d.]+)s\s+TRACE implicit step (\d+): \d+ \+ \d+ iterations", log):
                            steps.setdefault(int(m.group(2)), (float(m.group(1)), 1))
                    k = sorted(steps)
                    if len(k) < 2:
                        sys.exit(f"bench_implicit.py: no per-step lines in the log of {' '.join(cmd)}; fix: --steps 3 or more")
                    # steps 2..S: the first step's time holds one-off work
                    step = (steps[k[-1]][0] - steps[k[0]][0]) / (len(k) - 1)
                    # the median step: past the first steps' transient under error control
                    median = statistics.median(steps[k[j]][0] - steps[k[j - 1]][0] for j in range(1, len(k)))
                    tr = sum(steps[j][1] for j in k[1:]) / (len(k) - 1)
                    its = [int(x) for m in re.finditer(r"TRACE implicit step \d+: (\d+) \+ (\d+) iterations", log) for x in m.groups()]
                    label = f"eprop implicit, {pre}" + ("" if a.accuracy == "inf" else f", accuracy {a.accuracy}, {tr:.1f} TR-BDF2 steps")
                    rows.append((n, int(nodes.group(1)), label, p, sum(its) / max(len(its), 1), step, median))
                    print(rows[-1], file=sys.stderr, flush=True)
            if a.no_petsc:
                continue
            op = os.path.join(work, f"A{n}.h5")
            run([eprop, "export-operator", os.path.join(work, f"box{n}_{a.pre.split(',')[0]}.toml"), "-o", op], env)
            for p in [int(x) for x in a.procs.split(",")]:
                for rtol in a.petsc_rtol.split(","):
                    cmd = ["/usr/bin/python3", os.path.join(HERE, "scripts", "bench_ksp.py"), op, "--rtol", rtol, "--pc", a.petsc_pc]
                    if p > 1:
                        cmd = ["mpirun", "--oversubscribe", "-n", str(p)] + cmd
                    for line in run(cmd, env).splitlines():
                        r = json.loads(line)
                        rows.append((n, int(r["rows"]), f"PETSc CG + {r['pc']}, rtol {rtol}", p, r["iterations_per_solve"], r["s_per_step"], r["s_per_step"]))
                        print(rows[-1], file=sys.stderr, flush=True)
    print("| box | solver | processes | iterations per solve | s per step (mean of steps 2-S) | median s per step |")
    print("|---|---|---|---|---|---|")
    for n, nodes, what, p, it, s, med in rows:
        print(f"| {n}^3 ({nodes} nodes) | {what} | {p} | {it:.1f} | {s:.3f} | {med:.3f} |")


if __name__ == "__main__":
    main()
