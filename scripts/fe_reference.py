#!/usr/bin/python3
"""Finite-element reference for the validation of eprop (docs/validation.md).

A compressible neo-Hookean block, 40 x 40 x 20 mm (SI units: metres, pascals, newtons), its
bottom face fixed, indented on its top face by a rigid, frictionless sphere of radius 5 mm,
quasi-static. Computed with DOLFINx 0.5 (Debian's python3-dolfinx) on one process:

- quadratic (P2) tetrahedra on a box mesh graded towards the indenter and the top face;
  symmetry planes through the indenter's axis (a quarter of the block for the centred press,
  a half for the off-centre one);
- contact by a penalty on the gap to the sphere: the energy k/2 * <R - |x + u - c|>_+^2 over
  the top face (k in Pa/m), so the contact pressure is k times the penetration;
- Newton's method (LU with MUMPS), the sphere moved down in load steps (halved on failure).

Writes, into --out-dir (default scenarios/validation/reference):

  force_centre.csv        indentation_m, force_N, contact_radius_m: the centred press up to 4 mm
                          (the part a fit may use)
  force_centre_deep.csv   the same press continued deeper (held out: a prediction)
  force_offcentre.csv     a press 8 mm off the centre (held out: a prediction)
  lines_centre.csv,       the displacement along three lines at each named depth:
  lines_offcentre.csv     vertical below the indenter, along x at the surface and at mid-depth
                          (depth_m, line, x, y, z, ux, uy, uz; positions undeformed, metres)
  reference.json          the parameters, the mesh, the penalty, the Newton counts, the runtime
  convergence.csv         with --convergence: the centred force at three mesh levels, and at
                          --level with ten times the penalty

The indentation is the sphere's depth below the undeformed top face (its travel from first
touch); the force is the downward force the sphere exerts on the block, whole block.
"""

import argparse
import csv
import json
import os
import sys
import time

import logging

try:
    import numpy as np
except ImportError:
    sys.exit("fe_reference.py: numpy is missing from this Python; fix: run it with Debian's Python, "
             "/usr/bin/python3 scripts/fe_reference.py (apt-get install python3-dolfinx)")

# the block, the material and the indenter (SI)
LX, LY, LZ = 0.04, 0.04, 0.02
YOUNG, POISSON = 5.0e3, 0.45
RADIUS = 0.005
CENTRE = (0.02, 0.02)
OFFCENTRE = (0.012, 0.02)
PENALTY = 1.0e9  # Pa/m
SMOOTH = 1.0e-6  # m: the width of the penalty's smoothing

FIT_DEPTHS = [0.5e-3, 1e-3, 2e-3, 3e-3, 4e-3]
DEEP_DEPTHS = [5e-3, 6e-3]
OFF_DEPTHS = [1e-3, 2e-3, 3e-3, 4e-3]
STEP = 0.5e-3


def graded(t, a, b, c, w, amp):
    """Maps t in [0, 1] onto [a, b] with cells about (1 + amp) times smaller near c."""
    s = np.linspace(a, b, 4001)
    rho = 1.0 + amp * np.exp(-(((s - c) / w) ** 2))
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (rho[1:] + rho[:-1]) * np.diff(s))])
    cdf /= cdf[-1]
    return np.interp(t, cdf, s)


class Block:
    """The block (or its symmetric part) at one mesh level, pressed at (x0, y0)."""

    def __init__(self, x0, y0, level, penalty):
        from mpi4py import MPI
        import ufl
        from dolfinx import fem, mesh
        from petsc4py import PETSc

        logging.getLogger().setLevel(logging.WARNING)  # not the form compiler's lines
        self.fem, self.ufl = fem, ufl
        self.x0, self.y0 = x0, y0
        # symmetry: a quarter when the indenter is at the centre, else a half (y >= y0)
        self.sym_x = abs(x0 - LX / 2) < 1e-12
        xa = x0 if self.sym_x else 0.0
        ya = y0
        self.factor = (2.0 if self.sym_x else 1.0) * 2.0
        nx = level if self.sym_x else level + level // 2
        ny, nz = level, level
        msh = mesh.create_box(
            MPI.COMM_SELF, [np.zeros(3), np.ones(3)], [nx, ny, nz], mesh.CellType.tetrahedron
        )
        g = msh.geometry.x
        w = RADIUS
        g[:, 0] = graded(g[:, 0], xa, LX, x0, w, 6.0)
        g[:, 1] = graded(g[:, 1], ya, LY, y0, w, 6.0)
        g[:, 2] = graded(g[:, 2], 0.0, LZ, LZ, w, 4.0)
        self.msh = msh
        V = fem.VectorFunctionSpace(msh, ("Lagrange", 2))
        self.V = V
        self.dofs = V.dofmap.index_map.size_global * V.dofmap.index_map_bs
        fdim = 2
        tol = 1e-9

        def facets(f):
            return mesh.locate_entities_boundary(msh, fdim, f)

        bottom = facets(lambda x: x[2] < tol)
        bcs = [fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType),
                               fem.locate_dofs_topological(V, fdim, bottom), V)]
        zero = PETSc.ScalarType(0.0)
        if self.sym_x:
            f = facets(lambda x: np.abs(x[0] - xa) < tol)
            bcs.append(fem.dirichletbc(zero, fem.locate_dofs_topological(V.sub(0), fdim, f), V.sub(0)))
        f = facets(lambda x: np.abs(x[1] - ya) < tol)
        bcs.append(fem.dirichletbc(zero, fem.locate_dofs_topological(V.sub(1), fdim, f), V.sub(1)))
        top = facets(lambda x: np.abs(x[2] - LZ) < tol)
        tags = mesh.meshtags(msh, fdim, np.sort(top), 1)
        ds = ufl.Measure("ds", domain=msh, subdomain_data=tags, metadata={"quadrature_degree": 6})
        dx = ufl.Measure("dx", domain=msh, metadata={"quadrature_degree": 4})
        hx = np.diff(np.unique(np.round(g[:, 0], 12)))
        self.h_min = float(hx.min())

        u = fem.Function(V)
        v = ufl.TestFunction(V)
        du = ufl.TrialFunction(V)
        self.u = u
        mu = YOUNG / (2 * (1 + POISSON))
        lmbda = YOUNG * POISSON / ((1 + POISSON) * (1 - 2 * POISSON))
        F = ufl.Identity(3) + ufl.grad(u)
        J = ufl.det(F)
        I1 = ufl.tr(F.T * F)
        psi = mu / 2 * (I1 - 3) - mu * ufl.ln(J) + lmbda / 2 * ufl.ln(J) ** 2
        self.c = fem.Constant(msh, np.array([x0, y0, LZ + RADIUS], dtype=PETSc.ScalarType))
        self.k = fem.Constant(msh, PETSc.ScalarType(penalty))
        X = ufl.SpatialCoordinate(msh)
        d = X + u - self.c
        r = ufl.sqrt(ufl.dot(d, d))
        pen = RADIUS - r
        # a C2 penalty: k g^3 / (6 eps) for 0 < g < eps, k/2 (g^2 - eps g + eps^2/3) beyond,
        # so the pressure k (g - eps/2) is k g shifted by eps/2 (SMOOTH, far below the depths)
        eps = SMOOTH
        pos = ufl.conditional(ufl.gt(pen, 0.0), pen, 0.0)
        phi = ufl.conditional(ufl.gt(pen, eps), 0.5 * (pen**2 - eps * pen + eps**2 / 3),
                              pos**3 / (6 * eps))
        pressure = ufl.conditional(ufl.gt(pen, eps), pen - eps / 2, pos**2 / (2 * eps))
        energy = psi * dx + self.k * phi * ds(1)
        R = ufl.derivative(energy, u, v)
        Jac = ufl.derivative(R, u, du)
        # the force the sphere exerts on the block (this part), and the contact area
        self.fz = fem.form(-self.k * pressure * d[2] / r * ds(1))
        self.area = fem.form(ufl.conditional(ufl.gt(pen, 0.0), 1.0, 0.0) * ds(1))

        self.bcs = bcs
        self.Rf, self.Jf, self.Ef = fem.form(R), fem.form(Jac), fem.form(energy)
        from dolfinx.fem.petsc import create_matrix, create_vector

        self.A = create_matrix(self.Jf)
        self.b = create_vector(self.Rf)
        self.du = self.A.createVecRight()
        ksp = PETSc.KSP().create(MPI.COMM_SELF)
        ksp.setOperators(self.A)
        ksp.setType("preonly")
        ksp.getPC().setType("lu")
        ksp.getPC().setFactorSolverType("mumps")
        self.ksp = ksp
        self.newton = 0
        self.failures = 0
        self.last = None
        self.depth = 0.0

    def energy(self):
        e = self.fem.assemble_scalar(self.Ef)
        return e if np.isfinite(e) else np.inf

    def solve(self, max_it=20):
        """Newton's method with a backtracking line search on the total potential energy
        (a step that inverts a cell, where ln J is not finite, or raises the energy is
        halved). Converged when the largest correction is below 1e-11 m. Returns the number of
        iterations, or None."""
        from dolfinx.fem.petsc import assemble_matrix, assemble_vector, set_bc
        from petsc4py import PETSc

        u = self.u
        e0 = self.energy()
        if not np.isfinite(e0):
            return None
        for it in range(1, max_it + 1):
            self.A.zeroEntries()
            assemble_matrix(self.A, self.Jf, self.bcs)
            self.A.assemble()
            with self.b.localForm() as loc:
                loc.set(0.0)
            assemble_vector(self.b, self.Rf)
            self.b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            set_bc(self.b, self.bcs, u.vector, -1.0)
            self.ksp.solve(self.b, self.du)
            if self.ksp.getConvergedReason() < 0:
                return None
            step = self.du.array.copy()
            if not np.isfinite(step).all():
                return None
            base = u.x.array.copy()
            alpha = 1.0
            while True:
                u.x.array[:] = base - alpha * step
                e = self.energy()
                if e <= e0 + 1e-10 * abs(e0):
                    break
                alpha /= 2
                if alpha < 1e-4:
                    u.x.array[:] = base
                    return None
            e0 = e
            if alpha == 1.0 and np.abs(step).max() < 1e-11:
                return it
        return None

    def set_depth(self, depth):
        self.c.value[2] = LZ + RADIUS - depth

    def press_to(self, depth, step=STEP):
        """Moves the sphere down to depth in load steps (halved when Newton fails)."""
        while self.depth < depth - 1e-15:
            h = min(step, depth - self.depth)
            backup = self.u.x.array.copy()
            while True:
                self.set_depth(self.depth + h)
                # predictor: the last step's increment, scaled to this one (unless it inverts a cell)
                if self.last is not None:
                    self.u.x.array[:] = backup + (backup - self.last[0]) * (h / self.last[1])
                    if not np.isfinite(self.energy()):
                        self.u.x.array[:] = backup
                n = self.solve()
                if n is not None:
                    self.newton += n
                    self.depth += h
                    self.last = (backup, h)
                    break
                self.failures += 1
                self.u.x.array[:] = backup
                h /= 2
                if h < step / 64:
                    raise RuntimeError(f"Newton fails at depth {self.depth + h:.4g} m")

    def force(self):
        fem = self.fem
        f = fem.assemble_scalar(self.fz) * self.factor
        a = fem.assemble_scalar(self.area) * self.factor
        return float(f), float(np.sqrt(max(a, 0.0) / np.pi))

    def sample(self, points):
        """u at undeformed points of the whole block (mirrored into the modelled part)."""
        from dolfinx import geometry

        p = np.array(points, dtype=float)
        sign = np.ones((len(p), 3))
        if self.sym_x:
            m = p[:, 0] < self.x0
            p[m, 0] = 2 * self.x0 - p[m, 0]
            sign[m, 0] = -1.0
        m = p[:, 1] < self.y0
        p[m, 1] = 2 * self.y0 - p[m, 1]
        sign[m, 1] = -1.0
        lo = np.array([0.0, 0.0, 0.0]) + 1e-12
        hi = np.array([LX, LY, LZ]) - 1e-12
        p = np.clip(p, lo, hi)
        tree = geometry.BoundingBoxTree(self.msh, 3)
        cand = geometry.compute_collisions(tree, p)
        cells = geometry.compute_colliding_cells(self.msh, cand, p)
        idx = []
        for i in range(len(p)):
            c = cells.links(i)
            if len(c) == 0:
                raise RuntimeError(f"point {p[i]} is outside the mesh")
            idx.append(c[0])
        return self.u.eval(p, np.array(idx, dtype=np.int32)) * sign


def lines(x0, y0, n=41):
    """The three sampling lines through the indentation point: (name, points)."""
    z = np.linspace(0.0, LZ, n)
    x = np.linspace(0.0, LX, 2 * n - 1)
    return [
        ("vertical", np.column_stack([np.full_like(z, x0), np.full_like(z, y0), z])),
        ("surface", np.column_stack([x, np.full_like(x, y0), np.full_like(x, LZ)])),
        ("middepth", np.column_stack([x, np.full_like(x, y0), np.full_like(x, LZ / 2)])),
    ]


def press(x0, y0, level, penalty, depths, record, out_lines=None, log=None):
    """Presses to each depth in turn; returns [(depth, force, contact radius)] at every step
    boundary of `record` (STEP apart) and the named depths, and writes the lines."""
    t0 = time.perf_counter()
    b = Block(x0, y0, level, penalty)
    if log:
        log(f"  {b.dofs} unknowns, smallest cell edge {b.h_min * 1e3:.3f} mm")
    targets = sorted(set(np.round(np.concatenate([np.arange(1, round(max(depths) / STEP) + 1) * STEP,
                                                  depths]), 12)))
    rows = []
    writer = None
    if out_lines is not None:
        writer = csv.writer(out_lines)
        writer.writerow(["depth_m", "line", "x", "y", "z", "ux", "uy", "uz"])
    for d in targets:
        b.press_to(d)
        f, a = b.force()
        if record(d) or any(abs(d - t) < 1e-12 for t in depths):
            rows.append((d, f, a))
        if log:
            log(f"  depth {d * 1e3:5.2f} mm  force {f:.6e} N  contact radius {a * 1e3:.3f} mm  "
                f"(Newton {b.newton}, failures {b.failures}, {time.perf_counter() - t0:.0f} s)")
        if writer is not None and any(abs(d - t) < 1e-12 for t in depths):
            for name, pts in lines(x0, y0):
                u = b.sample(pts)
                for p, ui in zip(pts, u):
                    writer.writerow([f"{d:.6g}", name] + [f"{v:.6g}" for v in p] + [f"{v:.7g}" for v in ui])
    return b, rows


def write_force(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["indentation_m", "force_N", "contact_radius_m"])
        for d, F, a in rows:
            w.writerow([f"{d:.6g}", f"{F:.9g}", f"{a:.6g}"])


def hertz(d):
    es = YOUNG / (1 - POISSON**2)
    return 4.0 / 3.0 * es * np.sqrt(RADIUS) * d**1.5


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out-dir", default=os.path.join(os.path.dirname(__file__), "..", "scenarios",
                                                      "validation", "reference"),
                    help="where the CSV and JSON files go (default scenarios/validation/reference)")
    ap.add_argument("--level", type=int, default=8,
                    help="mesh level: cells along each edge of the modelled quarter (default 8, the reference)")
    ap.add_argument("--penalty", type=float, default=PENALTY, help="contact penalty k in Pa/m")
    ap.add_argument("--convergence", action="store_true",
                    help="also the centred press to 4 mm at the --convergence-levels, and at --level with ten "
                    "times the penalty (convergence.csv)")
    ap.add_argument("--convergence-levels", default="6,8,10", help="the levels of --convergence")
    ap.add_argument("--cases", default="centre,offcentre",
                    help="which presses to compute: centre, offcentre (comma-separated) or none")
    ap.add_argument("--convergence-file", default="convergence.csv", help="where --convergence writes (in --out-dir)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    a = ap.parse_args()
    try:
        import dolfinx  # noqa: F401
    except ImportError:
        sys.exit("fe_reference.py: DOLFINx is not installed; fix: apt-get install python3-dolfinx "
                 "(and run this script with /usr/bin/python3, Debian's Python)")
    cases = [c for c in a.cases.split(",") if c and c != "none"]
    for c in cases:
        if c not in ("centre", "offcentre"):
            sys.exit(f"fe_reference.py: --cases {a.cases}: {c!r} is not a case; fix: centre, offcentre or none")
    out = os.path.abspath(a.out_dir)
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        sys.exit(f"fe_reference.py: --out-dir {a.out_dir}: {e.strerror}; fix: a directory (or a new path)")

    def log(s):
        if not a.quiet:
            print(s, flush=True)

    t0 = time.perf_counter()
    meta_path = os.path.join(out, "reference.json")
    meta = {}
    if os.path.exists(meta_path):
        with open(meta_path) as f:
            meta = json.load(f)
    meta.update({
        "block_m": [LX, LY, LZ], "young_Pa": YOUNG, "poisson": POISSON, "radius_m": RADIUS,
        "law": "compressible neo-Hookean: mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2",
        "element": "P2 tetrahedra", "level": a.level, "penalty_Pa_per_m": a.penalty,
        "penalty_smoothing_m": SMOOTH, "load_step_m": STEP, "centre": list(CENTRE),
        "offcentre": list(OFFCENTRE), "dolfinx": __import__("dolfinx").__version__,
    })

    def save():
        with open(meta_path, "w") as f:
            json.dump(meta, f, indent=1)
            f.write("\n")

    on_grid = lambda d: True  # noqa: E731  every load step is a row of the curve
    if "centre" in cases:
        log(f"centred press at level {a.level}")
        s = time.perf_counter()
        with open(os.path.join(out, "lines_centre.csv"), "w", newline="") as fl:
            b, rows = press(*CENTRE, a.level, a.penalty, FIT_DEPTHS + DEEP_DEPTHS, on_grid, fl, log)
        write_force(os.path.join(out, "force_centre.csv"), [r for r in rows if r[0] <= FIT_DEPTHS[-1] + 1e-12])
        write_force(os.path.join(out, "force_centre_deep.csv"), [r for r in rows if r[0] > FIT_DEPTHS[-1] + 1e-12])
        meta["centre_run"] = {"unknowns": b.dofs, "smallest_edge_m": b.h_min, "newton_iterations": b.newton,
                              "failed_steps": b.failures, "seconds": round(time.perf_counter() - s, 1),
                              "force_over_hertz_0.5mm": [r[1] for r in rows if abs(r[0] - 0.5e-3) < 1e-12][0]
                              / hertz(0.5e-3)}
        save()
    if "offcentre" in cases:
        log(f"off-centre press at level {a.level}")
        s = time.perf_counter()
        with open(os.path.join(out, "lines_offcentre.csv"), "w", newline="") as fl:
            b, rows = press(*OFFCENTRE, a.level, a.penalty, OFF_DEPTHS, on_grid, fl, log)
        write_force(os.path.join(out, "force_offcentre.csv"), rows)
        meta["offcentre_run"] = {"unknowns": b.dofs, "smallest_edge_m": b.h_min, "newton_iterations": b.newton,
                                 "failed_steps": b.failures, "seconds": round(time.perf_counter() - s, 1)}
        save()
    if a.convergence:
        conv = []
        depths = [0.5e-3, 1e-3, 2e-3, 4e-3]
        levels = [int(v) for v in a.convergence_levels.split(",")]
        for level, k in [(lv, a.penalty) for lv in levels] + [(a.level, a.penalty * 10)]:
            log(f"convergence: level {level}, penalty {k:.3g}")
            s = time.perf_counter()
            b, rows = press(*CENTRE, level, k, depths, lambda d: False, None, log)
            for d, F, r in rows:
                if any(abs(d - t) < 1e-12 for t in depths):
                    conv.append((level, b.dofs, b.h_min, k, d, F, r, time.perf_counter() - s))
            with open(os.path.join(out, a.convergence_file), "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(["level", "unknowns", "smallest_edge_m", "penalty_Pa_per_m", "indentation_m", "force_N",
                            "contact_radius_m", "seconds"])
                for row in conv:
                    w.writerow([row[0], row[1], f"{row[2]:.4g}", f"{row[3]:.3g}", f"{row[4]:.6g}",
                                f"{row[5]:.9g}", f"{row[6]:.6g}", f"{row[7]:.1f}"])
    save()
    log(f"wrote {out} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
