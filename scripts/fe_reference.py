#!/usr/bin/python3
"""Finite-element reference for the validation of eprop (docs/validation.md).

A compressible neo-Hookean block, 40 x 40 x 20 mm (SI units: metres, pascals, newtons), its
bottom face fixed, indented on its top face, quasi-static, at its centre (20, 20) mm and 8 mm
off it (12, 20) mm, by two rigid indenters:

- a frictionless sphere of radius 5 mm: contact by a penalty on the gap to the sphere, a C2
  energy k g^3 / (6 eps) (0 < g < eps), k/2 (g^2 - eps g + eps^2/3) (g > eps) of the
  penetration g over the top face (k in Pa/m); P2 tetrahedra on a structured box graded towards
  the indenter and the top face;
- a sticky flat circular punch of radius 5 mm: the top face under it (r <= 5 mm, bonded from
  first touch) moves with it, u = (0, 0, -depth), and the rest of the top face is kept out of
  the punch's body (a cylinder above its face; the sphere's penalty, frictionless); the force is
  the reaction on the face plus the vertical part of that contact's; P2 tetrahedra on a gmsh
  mesh whose top face is split along the punch's rim, graded towards the rim (its stress
  singularity).

Computed with DOLFINx 0.5 (Debian's python3-dolfinx; the punch's mesh needs python3-gmsh) on
one process, with symmetry planes through the indenter's axis (a quarter of the block for the
centred press, a half for the off-centre one), Newton's method (LU with MUMPS) with an energy
line search, the indenter moved down in load steps of 0.5 mm (halved on failure), to 6 mm.

Writes, into --out-dir (default scenarios/validation/reference), per indenter (sphere, punch)
and position (centre, offcentre):

  force_<indenter>_<position>.csv   indentation_m, force_N, contact_radius_m, set: every load
                                    step (0.5 mm) to 6 mm
  lines_<indenter>_<position>.csv   depth_m, line, x, y, z, ux, uy, uz, set: the displacement
                                    at 0.5, 1, 2, 3, 4, 5, 6 mm along four lines through the
                                    indentation point (x0, y0): vertical (x0, y0, z), along x on
                                    the top face (surface) and at mid-depth (middepth), along y
                                    on the top face (surface_y); positions undeformed, metres
  surface_<indenter>_<position>_<d>mm.csv   x, y, ux, uy, uz on the undeformed top face every
                                    1 mm (41 x 41 points), at 3 and 6 mm (and the deepest depth
                                    reached, if a press stops short)

  The column set is "fit" for a centred press to 3 mm (the shallow half a fit may use) and
  "heldout" for the rest (deeper, off-centre); the surface grids are all held out.

  The sphere's files of the first validation, read by validate_compare.py, are still written:
  force_centre.csv (to 4 mm), force_centre_deep.csv (4.5-6 mm), force_offcentre.csv (to 4 mm):
  indentation_m, force_N, contact_radius_m; lines_centre.csv (0.5-6 mm), lines_offcentre.csv
  (1-4 mm): depth_m, line, x, y, z, ux, uy, uz (vertical, surface, middepth).

  reference.json          the parameters, the meshes, the Newton counts, the runtimes
  convergence.csv         with --convergence: the centred sphere force at three mesh levels, and
                          at --level with ten times the penalty
  convergence_punch.csv   with --convergence-punch: the centred punch force at several levels

The indentation is the indenter's depth below the undeformed top face (its travel from first
touch); the force is the downward force the indenter exerts on the block, whole block.
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

PUNCH_RADIUS = 0.005  # m: the flat punch

# the depths of the older sphere files (force_centre.csv to 4 mm, force_centre_deep.csv beyond,
# force_offcentre.csv to 4 mm, lines_offcentre.csv at 1-4 mm), which validate_compare.py reads
FIT_DEPTHS = [0.5e-3, 1e-3, 2e-3, 3e-3, 4e-3]
DEEP_DEPTHS = [5e-3, 6e-3]
OFF_DEPTHS = [1e-3, 2e-3, 3e-3, 4e-3]
OLD_OFF_END = 4e-3
# every press: to 6 mm, the lines at these depths; the shallow half (the centred presses to
# 3 mm) is the part a fit may use, the rest (deeper, off-centre, the surface grids) is held out
DEPTHS = [0.5e-3, 1e-3, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3]
FIT_END = 3e-3
GRID_DEPTHS = [3e-3, 6e-3]  # the top-face grids (and the deepest depth reached, if less)
GRID_SPACING = 1e-3
PUNCH_LEVEL = 8
STEP = 0.5e-3


def fit_set(position, depth):
    """"fit" for the shallow half of a centred press, else "heldout"."""
    return "fit" if position == "centre" and depth <= FIT_END + 1e-12 else "heldout"


def graded(t, a, b, c, w, amp):
    """Maps t in [0, 1] onto [a, b] with cells about (1 + amp) times smaller near c."""
    s = np.linspace(a, b, 4001)
    rho = 1.0 + amp * np.exp(-(((s - c) / w) ** 2))
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (rho[1:] + rho[:-1]) * np.diff(s))])
    cdf /= cdf[-1]
    return np.interp(t, cdf, s)


def punch_mesh(x0, y0, xa, ya, level):
    """The block's part [xa, LX] x [ya, LY] x [0, LZ] meshed with gmsh, its top face split along
    the punch's rim (a circle of PUNCH_RADIUS about (x0, y0)), the tetrahedra graded towards the
    rim: size min(LZ / level, LZ / (10 level) + 0.25 r) at the distance r from the rim (LZ / level
    away from it, a tenth of that on it). Returns the mesh and the facet tags (2: the face under
    the punch)."""
    import gmsh
    from mpi4py import MPI
    from dolfinx.io import gmshio

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("block")
        occ = gmsh.model.occ
        box = occ.addBox(xa, ya, 0.0, LX - xa, LY - ya, LZ)
        disk = occ.addDisk(x0, y0, LZ, PUNCH_RADIUS, PUNCH_RADIUS)
        rect = occ.addRectangle(xa, ya, LZ, LX - xa, LY - ya)
        sector, _ = occ.intersect([(2, disk)], [(2, rect)])
        occ.fragment([(3, box)], sector)
        occ.synchronize()
        disc, rim = [], []
        for _, e in gmsh.model.getEntities(2):
            c = occ.getCenterOfMass(2, e)
            if abs(c[2] - LZ) < 1e-9 and np.hypot(c[0] - x0, c[1] - y0) < PUNCH_RADIUS:
                disc.append(e)
        for _, e in gmsh.model.getEntities(1):
            lo, hi = gmsh.model.getParametrizationBounds(1, e)
            p = gmsh.model.getValue(1, e, [0.5 * (lo[0] + hi[0])])
            if abs(p[2] - LZ) < 1e-9 and abs(np.hypot(p[0] - x0, p[1] - y0) - PUNCH_RADIUS) < 1e-9:
                rim.append(e)
        if not disc or not rim:
            raise RuntimeError("gmsh: the punch's face or rim was not found on the top face")
        gmsh.model.addPhysicalGroup(3, [e for _, e in gmsh.model.getEntities(3)], 1)
        gmsh.model.addPhysicalGroup(2, disc, 2)
        rest = [e for _, e in gmsh.model.getEntities(2)
                if e not in disc and abs(occ.getCenterOfMass(2, e)[2] - LZ) < 1e-9]
        gmsh.model.addPhysicalGroup(2, rest, 3)
        h_far = LZ / level
        h_rim = h_far / 10
        f = gmsh.model.mesh.field
        fd = f.add("Distance")
        f.setNumbers(fd, "CurvesList", rim)
        f.setNumber(fd, "NumPointsPerCurve", 400)
        fm = f.add("MathEval")
        f.setString(fm, "F", f"Min({h_far}, {h_rim} + 0.25 * F{fd})")
        f.setAsBackgroundMesh(fm)
        for o in ("Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature", "Mesh.MeshSizeExtendFromBoundary"):
            gmsh.option.setNumber(o, 0)
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(3)
        msh, _, ft = gmshio.model_to_mesh(gmsh.model, MPI.COMM_SELF, 0, gdim=3)
    finally:
        gmsh.finalize()
    return msh, ft, h_rim


class Block:
    """The block (or its symmetric part) at one mesh level, pressed at (x0, y0) by the sphere
    (indenter "sphere") or by the sticky flat punch ("punch")."""

    def __init__(self, x0, y0, level, penalty, indenter="sphere"):
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
        self.indenter = indenter
        if indenter == "sphere":
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
        else:
            msh, ftags, h_rim = punch_mesh(x0, y0, xa, ya, level)
            g = msh.geometry.x
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
        if indenter == "sphere":
            hx = np.diff(np.unique(np.round(g[:, 0], 12)))
            self.h_min = float(hx.min())
        else:
            msh.topology.create_connectivity(1, 0)
            e = msh.topology.connectivity(1, 0).array.reshape(-1, 2)
            self.h_min = float(np.linalg.norm(g[e[:, 0]] - g[e[:, 1]], axis=1).min())
            self.h_rim = h_rim
        self.cells = msh.topology.index_map(3).size_local

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
        self.lifting = indenter == "punch"
        if indenter == "punch":
            # sticky: the top face under the punch moves with it, u = (0, 0, -depth)
            disc = ftags.find(2)
            self.g = fem.Constant(msh, np.zeros(3, dtype=PETSc.ScalarType))
            self.disc_bc = fem.dirichletbc(self.g, fem.locate_dofs_topological(V, fdim, disc), V)
            bcs.append(self.disc_bc)
            self.disc_z = fem.locate_dofs_topological(V.sub(2), fdim, disc)
            self.bcs = bcs
            # and the rest of the top face stays out of the punch (a rigid cylinder r < a above
            # its face, frictionless): the sphere's C2 penalty on the penetration, the smaller of
            # the depth inside the side (a - r) and above the face (z - face)
            self.k = fem.Constant(msh, PETSc.ScalarType(penalty))
            self.face = fem.Constant(msh, PETSc.ScalarType(LZ))
            x = ufl.SpatialCoordinate(msh) + u
            r = ufl.sqrt((x[0] - x0) ** 2 + (x[1] - y0) ** 2)
            pen = ufl.min_value(PUNCH_RADIUS - r, x[2] - self.face)
            eps = SMOOTH
            pos = ufl.conditional(ufl.gt(pen, 0.0), pen, 0.0)
            phi = ufl.conditional(ufl.gt(pen, eps), 0.5 * (pen**2 - eps * pen + eps**2 / 3),
                                  pos**3 / (6 * eps))
            dsp = ufl.Measure("ds", domain=msh, subdomain_data=ftags, metadata={"quadrature_degree": 6})
            side = self.k * phi * dsp(3)
            energy = psi * dx + side
            R = ufl.derivative(energy, u, v)
            Jac = ufl.derivative(R, u, du)
            self.Rf, self.Jf, self.Ef = fem.form(R), fem.form(Jac), fem.form(energy)
            self.Rside = fem.form(ufl.derivative(side, u, v))
            self.side_area = fem.form(ufl.conditional(ufl.gt(pen, 0.0), 1.0, 0.0) * dsp(3))
            self._solver(MPI, PETSc)
            return
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
        self._solver(MPI, PETSc)

    def _solver(self, MPI, PETSc):
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
        self.exact_bc = True  # the punch's face is where the punch is

    def energy(self):
        e = self.fem.assemble_scalar(self.Ef)
        return e if np.isfinite(e) else np.inf

    def solve(self, max_it=20):
        """Newton's method with a backtracking line search on the total potential energy
        (a step that inverts a cell, where ln J is not finite, or raises the energy is
        halved). Converged when the largest correction is below 1e-11 m. Returns the number of
        iterations, or None."""
        from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, set_bc
        from petsc4py import PETSc

        u = self.u
        e0 = self.energy()
        if not np.isfinite(e0):
            return None
        for it in range(1, max_it + 1):
            # the punch: while its face is not yet where the punch is (the first iteration of a
            # load step without a predictor), the full Newton step (which puts it there) is
            # taken as long as no cell inverts; the energy decides only from then on
            moving = not self.exact_bc
            self.A.zeroEntries()
            assemble_matrix(self.A, self.Jf, self.bcs)
            self.A.assemble()
            with self.b.localForm() as loc:
                loc.set(0.0)
            assemble_vector(self.b, self.Rf)
            if self.lifting:
                apply_lifting(self.b, [self.Jf], bcs=[self.bcs], x0=[u.vector], scale=-1.0)
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
            if moving:
                u.x.array[:] = base - step
                set_bc(u.vector, [self.disc_bc])  # exactly the punch's depth
                e0 = self.energy()
                if not np.isfinite(e0):
                    u.x.array[:] = base
                    return None
                self.exact_bc = True
                continue
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
        if self.indenter == "punch":
            self.g.value[2] = -depth
            self.face.value = LZ - depth
            self.exact_bc = False
        else:
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
                    if self.lifting:
                        from dolfinx.fem.petsc import set_bc

                        set_bc(self.u.vector, [self.disc_bc])
                        self.exact_bc = True
                    if not np.isfinite(self.energy()):
                        self.u.x.array[:] = backup
                        self.exact_bc = not self.lifting
                n = self.solve()
                if n is not None:
                    self.newton += n
                    self.depth += h
                    self.last = (backup, h)
                    break
                self.failures += 1
                self.u.x.array[:] = backup
                self.exact_bc = not self.lifting
                h /= 2
                if h < step / 64:
                    raise RuntimeError(f"Newton fails at depth {self.depth + h:.4g} m")

    def force(self):
        fem = self.fem
        if self.indenter == "punch":
            # the reaction on the punch's face: the elastic residual at its vertical unknowns
            from dolfinx.fem.petsc import assemble_vector

            # the reaction on the punch's face (the residual at its vertical unknowns) and the
            # vertical part of the contact force on its side and edge (the penalty's residual
            # elsewhere)
            with self.b.localForm() as loc:
                loc.set(0.0)
            assemble_vector(self.b, self.Rf)
            f = -float(np.sum(self.b.array[self.disc_z]))
            with self.b.localForm() as loc:
                loc.set(0.0)
            assemble_vector(self.b, self.Rside)
            z = self.b.array[2::3]
            f += float(np.sum(z) - np.sum(self.b.array[self.disc_z]))
            self.side = fem.assemble_scalar(self.side_area) * self.factor
            return f * self.factor, PUNCH_RADIUS
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
                # a point on a face or an edge the search missed: 10 nm towards the block's middle
                q = p[i] + 1e-8 * np.sign(np.array([LX / 2, LY / 2, LZ / 2]) - p[i])
                c = geometry.compute_colliding_cells(self.msh, geometry.compute_collisions(tree, q[None, :]),
                                                     q[None, :]).links(0)
                if len(c) == 0:
                    raise RuntimeError(f"point {p[i]} is outside the mesh")
                p[i] = q
            idx.append(c[0])
        return self.u.eval(p, np.array(idx, dtype=np.int32)) * sign


def lines(x0, y0, n=41, along_y=False):
    """The sampling lines through the indentation point: (name, points). vertical, surface (along
    x on the top face) and middepth (along x at z = LZ / 2); with along_y also surface_y (along y
    on the top face)."""
    z = np.linspace(0.0, LZ, n)
    x = np.linspace(0.0, LX, 2 * n - 1)
    out = [
        ("vertical", np.column_stack([np.full_like(z, x0), np.full_like(z, y0), z])),
        ("surface", np.column_stack([x, np.full_like(x, y0), np.full_like(x, LZ)])),
        ("middepth", np.column_stack([x, np.full_like(x, y0), np.full_like(x, LZ / 2)])),
    ]
    if along_y:
        y = np.linspace(0.0, LY, 2 * n - 1)
        out.append(("surface_y", np.column_stack([np.full_like(y, x0), y, np.full_like(y, LZ)])))
    return out


def top_grid():
    """The undeformed top face sampled every GRID_SPACING (x fastest)."""
    x = np.linspace(0.0, LX, int(round(LX / GRID_SPACING)) + 1)
    y = np.linspace(0.0, LY, int(round(LY / GRID_SPACING)) + 1)
    X, Y = np.meshgrid(x, y)
    return np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, LZ)])


def named(d, depths):
    return any(abs(d - t) < 1e-12 for t in depths)


def press(x0, y0, level, penalty, depths, indenter="sphere", at_depth=None, log=None):
    """Presses in load steps of STEP to each depth in turn; returns the Block, the rows (depth,
    force, contact radius) of every step boundary and named depth, and the failure's message
    (None when the press reached the deepest depth). Calls at_depth(block, depth) at each of
    `depths`."""
    t0 = time.perf_counter()
    b = Block(x0, y0, level, penalty, indenter)
    if log:
        log(f"  {b.dofs} unknowns, {b.cells} cells, smallest cell edge {b.h_min * 1e3:.3f} mm")
    targets = sorted(set(np.round(np.concatenate([np.arange(1, round(max(depths) / STEP) + 1) * STEP,
                                                  depths]), 12)))
    rows = []
    stopped = None
    for d in targets:
        try:
            b.press_to(d)
        except RuntimeError as e:
            stopped = str(e)
            if log:
                log(f"  stopped: {stopped} (Newton {b.newton}, failures {b.failures})")
            break
        f, a = b.force()
        rows.append((d, f, a))
        if log:
            side = f", side contact {b.side * 1e6:.3f} mm2" if indenter == "punch" else ""
            log(f"  depth {d * 1e3:5.2f} mm  force {f:.6e} N  contact radius {a * 1e3:.3f} mm{side}  "
                f"(Newton {b.newton}, failures {b.failures}, {time.perf_counter() - t0:.0f} s)")
        if at_depth is not None and named(d, depths):
            at_depth(b, d)
    b.seconds = time.perf_counter() - t0
    return b, rows, stopped


def write_force(path, rows, position=None):
    """The force curve; with a position, the column set (fit_set)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["indentation_m", "force_N", "contact_radius_m"] + (["set"] if position else []))
        for d, F, a in rows:
            w.writerow([f"{d:.6g}", f"{F:.9g}", f"{a:.6g}"] + ([fit_set(position, d)] if position else []))


def write_lines(path, samples, names, depths, position=None):
    """samples: [(depth, line, points, u)]; only the lines in names at the depths in depths."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["depth_m", "line", "x", "y", "z", "ux", "uy", "uz"] + (["set"] if position else []))
        for d, name, pts, u in samples:
            if name not in names or not named(d, depths):
                continue
            extra = [fit_set(position, d)] if position else []
            for p, ui in zip(pts, u):
                w.writerow([f"{d:.6g}", name] + [f"{v:.6g}" for v in p] + [f"{v:.7g}" for v in ui] + extra)


def write_grid(path, pts, u):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "ux", "uy", "uz"])
        for p, ui in zip(pts, u):
            w.writerow([f"{p[0]:.6g}", f"{p[1]:.6g}"] + [f"{v:.7g}" for v in ui])


def hertz(d):
    es = YOUNG / (1 - POISSON**2)
    return 4.0 / 3.0 * es * np.sqrt(RADIUS) * d**1.5


def boussinesq_punch(d):
    """A rigid flat punch on a half-space, small strain (frictionless; bonded differs little)."""
    return 2.0 * PUNCH_RADIUS * YOUNG / (1 - POISSON**2) * d


CASES = {"centre": ("sphere", "centre"), "offcentre": ("sphere", "offcentre"),
         "punch-centre": ("punch", "centre"), "punch-offcentre": ("punch", "offcentre")}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out-dir", default=os.path.join(os.path.dirname(__file__), "..", "scenarios",
                                                      "validation", "reference"),
                    help="where the CSV and JSON files go (default scenarios/validation/reference)")
    ap.add_argument("--level", type=int, default=8,
                    help="the sphere's mesh level: cells along each edge of the modelled quarter (default 8, the "
                    "reference)")
    ap.add_argument("--punch-level", type=int, default=PUNCH_LEVEL,
                    help=f"the punch's mesh level: cell size 20 mm / level away from the rim, a tenth of it on "
                    f"the rim (default {PUNCH_LEVEL}, the reference)")
    ap.add_argument("--penalty", type=float, default=PENALTY, help="the sphere's contact penalty k in Pa/m")
    ap.add_argument("--convergence", action="store_true",
                    help="also the centred sphere press to 4 mm at the --convergence-levels, and at --level with "
                    "ten times the penalty (convergence.csv)")
    ap.add_argument("--convergence-levels", default="6,8,10", help="the levels of --convergence")
    ap.add_argument("--convergence-punch", action="store_true",
                    help="also the centred punch press at the --punch-convergence-levels (convergence_punch.csv; "
                    "the rows of other levels already in it are kept)")
    ap.add_argument("--punch-convergence-levels", default=f"4,6,{PUNCH_LEVEL}",
                    help="the levels of --convergence-punch")
    ap.add_argument("--cases", default=",".join(CASES),
                    help="which presses to compute, comma-separated: centre, offcentre (the sphere), punch-centre, "
                    "punch-offcentre, or none")
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
        if c not in CASES:
            sys.exit(f"fe_reference.py: --cases {a.cases}: {c!r} is not a case; fix: centre, offcentre, "
                     "punch-centre, punch-offcentre or none")
    if any(CASES[c][0] == "punch" for c in cases) or a.convergence_punch:
        try:
            import gmsh  # noqa: F401
        except ImportError:
            sys.exit("fe_reference.py: the punch's mesh needs gmsh's Python module; fix: apt-get install python3-gmsh")
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
    meta = {
        "block_m": [LX, LY, LZ], "young_Pa": YOUNG, "poisson": POISSON, "radius_m": RADIUS,
        "punch_radius_m": PUNCH_RADIUS,
        "law": "compressible neo-Hookean: mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2",
        "element": "P2 tetrahedra", "level": a.level, "punch_level": a.punch_level,
        "penalty_Pa_per_m": a.penalty, "penalty_smoothing_m": SMOOTH, "load_step_m": STEP,
        "centre": list(CENTRE), "offcentre": list(OFFCENTRE), "dolfinx": __import__("dolfinx").__version__,
        "sphere": "rigid, frictionless; contact by a C2 penalty on the top face",
        "punch": "rigid, flat, circular, sticky: the top face r <= punch_radius_m has u = (0, 0, -depth); "
                 "force = the reaction there",
        "sets": "fit: a centred press to 3 mm (force_*_centre.csv and lines_*_centre.csv rows with set = fit); "
                "heldout: deeper, off-centre, and every surface_*.csv grid",
    }

    previous = {}
    if os.path.exists(meta_path):
        with open(meta_path) as f:
            previous = json.load(f)

    def save():
        # merged with the file as it is now (another run may write other cases into it)
        cur = {}
        if os.path.exists(meta_path):
            with open(meta_path) as f:
                cur = json.load(f)
        for k, v in meta.items():
            if isinstance(v, dict) and isinstance(cur.get(k), dict):
                cur[k].update(v)
            else:
                cur[k] = v
        with open(meta_path, "w") as f:
            json.dump(cur, f, indent=1)
            f.write("\n")

    done = {}  # the punch's centred press at its reference level, reused by --convergence-punch
    for case in cases:
        indenter, position = CASES[case]
        x0, y0 = CENTRE if position == "centre" else OFFCENTRE
        level = a.level if indenter == "sphere" else a.punch_level
        log(f"{indenter}, {position}, level {level}")
        samples, grids = [], {}
        grid_pts = top_grid()

        def at_depth(b, d):
            for name, pts in lines(x0, y0, along_y=True):
                samples.append((d, name, pts, b.sample(pts)))
            grids[round(d, 12)] = b.sample(grid_pts)

        b, rows, stopped = press(x0, y0, level, a.penalty, DEPTHS, indenter, at_depth, log)
        tag = f"{indenter}_{position}"
        write_force(os.path.join(out, f"force_{tag}.csv"), rows, position)
        all_lines = ("vertical", "surface", "middepth", "surface_y")
        write_lines(os.path.join(out, f"lines_{tag}.csv"), samples, all_lines, DEPTHS, position)
        deepest = max(grids) if grids else None
        written = []
        for d in sorted(set(GRID_DEPTHS) | ({deepest} if deepest is not None else set())):
            if d in grids:
                name = f"surface_{tag}_{d * 1e3:g}mm.csv"
                write_grid(os.path.join(out, name), grid_pts, grids[d])
                written.append(name)
        old = ("vertical", "surface", "middepth")
        if case == "centre":  # the older files, read by validate_compare.py
            write_force(os.path.join(out, "force_centre.csv"), [r for r in rows if r[0] <= FIT_DEPTHS[-1] + 1e-12])
            write_force(os.path.join(out, "force_centre_deep.csv"), [r for r in rows if r[0] > FIT_DEPTHS[-1] + 1e-12])
            write_lines(os.path.join(out, "lines_centre.csv"), samples, old, FIT_DEPTHS + DEEP_DEPTHS)
        if case == "offcentre":
            write_force(os.path.join(out, "force_offcentre.csv"), [r for r in rows if r[0] <= OLD_OFF_END + 1e-12])
            write_lines(os.path.join(out, "lines_offcentre.csv"), samples, old, OFF_DEPTHS)
        run = {"unknowns": b.dofs, "cells": b.cells, "smallest_edge_m": b.h_min, "newton_iterations": b.newton,
               "failed_steps": b.failures, "seconds": round(b.seconds, 1),
               "deepest_m": rows[-1][0] if rows else 0.0, "stopped": stopped, "surface_grids": written}
        if indenter == "sphere" and position == "centre":
            run["force_over_hertz_0.5mm"] = [r[1] for r in rows if abs(r[0] - 0.5e-3) < 1e-12][0] / hertz(0.5e-3)
        if indenter == "punch":
            run["rim_cell_size_m"] = b.h_rim
            run["force_over_boussinesq_0.5mm"] = ([r[1] for r in rows if abs(r[0] - 0.5e-3) < 1e-12] or [np.nan])[0] \
                / boussinesq_punch(0.5e-3)
        meta[f"{case}_run".replace("-", "_")] = run
        if case == "punch-centre":
            done[a.punch_level] = (b, rows, stopped)
        save()
    if a.convergence:
        conv = []
        depths = [0.5e-3, 1e-3, 2e-3, 4e-3]
        levels = [int(v) for v in a.convergence_levels.split(",")]
        for level, k in [(lv, a.penalty) for lv in levels] + [(a.level, a.penalty * 10)]:
            log(f"convergence: level {level}, penalty {k:.3g}")
            b, rows, _ = press(*CENTRE, level, k, depths, "sphere", None, log)
            for d, F, r in rows:
                if named(d, depths):
                    conv.append((level, b.dofs, b.h_min, k, d, F, r, b.seconds))
            write_convergence(os.path.join(out, a.convergence_file), conv)
    if a.convergence_punch:
        conv = []
        for level in [int(v) for v in a.punch_convergence_levels.split(",")]:
            ref_run = meta.get("punch_centre_run") or previous.get("punch_centre_run")
            ref_level = meta.get("punch_level", 0) if "punch_centre_run" in meta else previous.get("punch_level")
            ref_file = os.path.join(out, "force_punch_centre.csv")
            if level in done:
                log(f"punch convergence: level {level} is the reference's centred press")
                b, rows, stopped = done[level]
            elif level == ref_level and ref_run and os.path.exists(ref_file):
                log(f"punch convergence: level {level} is the reference's centred press ({ref_file})")
                with open(ref_file, newline="") as f:
                    rows = [(float(r[0]), float(r[1]), float(r[2])) for r in list(csv.reader(f))[1:]]
                b = argparse.Namespace(dofs=ref_run["unknowns"], h_min=ref_run["smallest_edge_m"],
                                       seconds=ref_run["seconds"], cells=ref_run["cells"],
                                       h_rim=ref_run["rim_cell_size_m"], newton=ref_run["newton_iterations"],
                                       failures=ref_run["failed_steps"])
                stopped = ref_run["stopped"]
            else:
                log(f"punch convergence: level {level}")
                t_level = time.perf_counter()

                def at_depth(b, d, level=level, t_level=t_level):
                    # written at each depth, so a run stopped early leaves the depths it reached
                    F, r = b.force()
                    conv.append((level, b.dofs, b.h_min, 0.0, d, F, r, time.perf_counter() - t_level))
                    write_convergence(os.path.join(out, "convergence_punch.csv"), conv, punch=True)

                b, rows, stopped = press(*CENTRE, level, a.penalty, DEPTHS, "punch", at_depth, log)
                rows = []
            for d, F, r in rows:
                if named(d, DEPTHS):
                    conv.append((level, b.dofs, b.h_min, 0.0, d, F, r, b.seconds))
            write_convergence(os.path.join(out, "convergence_punch.csv"), conv, punch=True)
            meta.setdefault("punch_convergence", {})[str(level)] = {
                "unknowns": b.dofs, "cells": b.cells, "rim_cell_size_m": b.h_rim, "smallest_edge_m": b.h_min,
                "newton_iterations": b.newton, "failed_steps": b.failures, "seconds": round(b.seconds, 1),
                "stopped": stopped}
            save()
    save()
    log(f"wrote {out} in {time.perf_counter() - t0:.0f} s")


def write_convergence(path, conv, punch=False):
    """The convergence table; the punch's keeps the rows of other levels already in the file (so a
    finer level can be added by a later run)."""
    kept = []
    if punch and os.path.exists(path):
        with open(path, newline="") as f:
            kept = list(csv.reader(f))[1:]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        if punch:
            w.writerow(["level", "unknowns", "smallest_edge_m", "indentation_m", "force_N", "seconds"])
            rows = [[row[0], row[1], f"{row[2]:.4g}", f"{row[4]:.6g}", f"{row[5]:.9g}", f"{row[7]:.1f}"]
                    for row in conv]
            ours = {r[0] for r in rows}
            rows += [r for r in kept if int(r[0]) not in ours]
            w.writerows(sorted(rows, key=lambda r: (int(r[0]), float(r[3]))))
            return
        w.writerow(["level", "unknowns", "smallest_edge_m", "penalty_Pa_per_m", "indentation_m", "force_N",
                    "contact_radius_m", "seconds"])
        for row in conv:
            w.writerow([row[0], row[1], f"{row[2]:.4g}", f"{row[3]:.3g}", f"{row[4]:.6g}",
                        f"{row[5]:.9g}", f"{row[6]:.6g}", f"{row[7]:.1f}"])


if __name__ == "__main__":
    main()
