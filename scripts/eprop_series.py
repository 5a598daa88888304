#!/usr/bin/env python3
"""Reading eprop's VTKHDF series: the module the post-processing scripts share.

    import sys; sys.path.insert(0, "scripts")
    from eprop_series import open_series
    with open_series("out/cylinder.h5") as s:
        s.steps, s.times            # complete output steps and their times
        s.loads()                   # per [[load]]: node, force, displacement (steps, loads, 3)
        s.tools()                   # per [[tool]]: position, force, indentation, ... (or Fail)
        s.field("displacement", -1) # (N, 3) at the last complete step
        xyz, tris = s.surface(-1)   # deformed points and the outer surface's triangles

A series holds room for the steps its run will write: only the `/eprop/steps_complete`
steps are read (the counter a commit writes last). The header's counts are checked against
the datasets' extents on opening: a damaged or edited file is a `Fail`. Opening retries
briefly while the writer flushes. Errors are `Fail` (a one-line message naming the file and
the fix).

examples:
  eprop_series.py out/cylinder.h5          # lists steps, fields, loads, tools and probes
Run as a script it prints that listing."""
import sys
import time

import h5py
import numpy as np


class Fail(Exception):
    """An error reported to the user as a one-line message."""


# Faces of each VTK cell type, in the cell's local node numbering.
CELL_FACES = {
    10: [(0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3)],                      # tetra
    12: [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5),
         (2, 3, 7, 6), (3, 0, 4, 7)],                                       # hexahedron
    13: [(0, 1, 2), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)],  # wedge
    14: [(0, 1, 2, 3), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)],        # pyramid
}


def boundary_triangles(conn, offsets, types):
    """Triangles of the faces that belong to exactly one cell (quads split in two), (M, 3)."""
    faces = {3: [], 4: []}
    for t in np.unique(types):
        if t not in CELL_FACES:
            raise Fail(f"unsupported VTK cell type {t}")
        sel = np.flatnonzero(types == t)
        nodes = conn[offsets[sel][:, None] + np.arange(offsets[sel[0] + 1] - offsets[sel[0]])]
        for f in CELL_FACES[t]:
            faces[len(f)].append(nodes[:, f])
    tris = []
    for k, parts in faces.items():
        if not parts:
            continue
        fs = np.concatenate(parts)
        _, inv, cnt = np.unique(np.sort(fs, axis=1), axis=0, return_inverse=True, return_counts=True)
        fs = fs[cnt[inv.ravel()] == 1]
        tris.append(fs if k == 3 else np.concatenate([fs[:, [0, 1, 2]], fs[:, [0, 2, 3]]]))
    return np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)


def open_series(path, tries=50):
    """The series at `path` (a `Series`, also a context manager)."""
    last = None
    for _ in range(tries):
        try:
            f = h5py.File(path, "r")
        except FileNotFoundError:
            raise Fail(f"{path}: no such file")
        except OSError as e:  # the writer is flushing, or the file is damaged
            last = e
            time.sleep(0.05)
            continue
        if "eprop" not in f or "VTKHDF" not in f:
            f.close()
            raise Fail(f"{path}: not an eprop series (no /VTKHDF or /eprop group)")
        try:
            return Series(path, f)
        except Fail:
            f.close()
            raise
    raise Fail(f"{path}: cannot open: {last}")


def count_of(f):
    """The complete output steps of an open series: the counter /eprop/steps_complete (a
    dataset), or in a series written before it was one, the attribute of that name."""
    ep = f["eprop"]
    if ep.get("steps_complete", getclass=True) is h5py.Dataset:
        if ep["steps_complete"].shape != (1,):
            return None
        return int(ep["steps_complete"][0])
    if "steps_complete" in ep.attrs:
        return int(ep.attrs["steps_complete"])
    return None


def check_header(path, f):
    """(points N, complete steps K) of an open series, its counts checked against the
    extents of the datasets they describe: a damaged or edited header is a Fail naming what
    is wrong, before anything is read or allocated from it."""
    def damaged(what):
        return Fail(f"{path}: a damaged series: {what}; fix: restore the file from a copy, "
                    f"or write it again (eprop run ... --overwrite)")

    def one(name):
        if name not in f or not isinstance(f[name], h5py.Dataset) or f[name].shape != (1,):
            raise damaged(f"/{name} is not one count")
        return int(f[name][0])

    k = count_of(f)
    if k is None:
        raise Fail(f"{path}: not an eprop series (no /eprop steps_complete)")
    n, cells, conn = (one("VTKHDF/" + c) for c in
                      ("NumberOfPoints", "NumberOfCells", "NumberOfConnectivityIds"))
    if n < 1 or f["VTKHDF/Points"].shape != (n, 3):
        raise damaged(f"/VTKHDF/NumberOfPoints is {n} but /VTKHDF/Points holds "
                      f"{f['VTKHDF/Points'].shape} values")
    if cells < 1 or conn < 1:
        raise damaged(f"/VTKHDF/NumberOfCells is {cells} and NumberOfConnectivityIds {conn}")
    for name, want in (("Types", cells), ("Offsets", cells + 1), ("Connectivity", conn)):
        if f["VTKHDF/" + name].shape != (want,):
            raise damaged(f"/VTKHDF/{name} holds {f['VTKHDF/' + name].shape} entries, not {want}")
    held = [(f"/VTKHDF/PointData/{a}", d.shape[0] // n) for a, d in f["VTKHDF/PointData"].items()]
    held += [(f"/eprop/probes/{a}", f["eprop/probes/" + a].shape[0]) for a in ("time", "step")]
    if "eprop/tools" in f:
        held += [(f"/eprop/tools/{a}", d.shape[0]) for a, d in f["eprop/tools"].items()]
    for name, steps in held:
        if not 0 <= k <= steps:
            raise damaged(f"/eprop steps_complete is {k} but {name} holds {steps} steps (of {n} points)")
    return n, k


class Series:
    def __init__(self, path, f):
        self.path, self.f = path, f
        self.n, self.steps = check_header(path, f)
        if self.steps < 1:
            raise Fail(f"{path}: no complete output step yet")
        # the probes' times are the steps' times (/VTKHDF/Steps/Values is a copy for VTK)
        self.times = f["eprop/probes/time"][: self.steps]
        self.points = f["VTKHDF/Points"][:]

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.f.close()

    def step_index(self, k):
        """Output step k (negative: from the last complete step) as an index 0..steps-1."""
        kk = k + self.steps if k < 0 else k
        if not 0 <= kk < self.steps:
            raise Fail(f"{self.path}: output step {k} is not in the file ({self.steps} complete steps)")
        return kk

    def solver_steps(self):
        """The solver's step number of each complete output step, (S,)."""
        return self.f["eprop/probes/step"][: self.steps]

    def fields(self):
        """Names of the point fields written (displacement, velocity, potential, energy)."""
        return list(self.f["VTKHDF/PointData"].keys())

    def field(self, name, k):
        """Point field `name` at output step k: (N, 3) or (N,)."""
        if f"VTKHDF/PointData/{name}" not in self.f:
            raise Fail(f"{self.path}: no field `{name}` (the file has: {', '.join(self.fields())})")
        k = self.step_index(k)
        return np.asarray(self.f[f"VTKHDF/PointData/{name}"][k * self.n:(k + 1) * self.n], dtype=float)

    def cells(self):
        return (self.f["VTKHDF/Connectivity"][:], self.f["VTKHDF/Offsets"][:], self.f["VTKHDF/Types"][:])

    def surface(self, k=None, scale=1.0):
        """(points (N, 3), triangles (M, 3)) of the outer surface: the rest mesh, or at output
        step k moved by `scale` times the displacement."""
        pts = np.asarray(self.points, dtype=float)
        if k is not None:
            pts = pts + scale * self.field("displacement", k)
        return pts, boundary_triangles(*self.cells())

    def control_volumes(self):
        return self.f["eprop/control_volumes"][:]

    def loads(self):
        """The [[load]] probes over the complete steps: dict of node (L,) (0-based output node
        index), time, step (S,), force (applied) and displacement (of the contact) (S, L, 3).
        L is 0 for a run without loads."""
        p = self.f["eprop/probes"]
        node = p["node"][:].astype(np.int64)
        nl = len(node)  # files written before (S, 0, 3) hold one row of zeros without loads
        return {"node": node, "time": p["time"][: self.steps], "step": p["step"][: self.steps],
                "force": p["force"][: self.steps, :nl], "displacement": p["displacement"][: self.steps, :nl]}

    def n_loads(self):
        return len(self.f["eprop/probes/node"])

    def probes(self):
        """(force (S, L, 3), displacement (S, L, 3)) of the loads over the complete steps."""
        d = self.loads()
        return d["force"], d["displacement"]

    def n_tools(self):
        return int(self.f["eprop/tools/force"].shape[1]) if "eprop/tools" in self.f else 0

    def tools(self):
        """Per tool, over the complete steps: dict of time, step (S,), position, force,
        displacement (S, T, 3), contact_nodes, contact_area, indentation (S, T)."""
        if "eprop/tools" not in self.f:
            raise Fail(f"{self.path}: the run has no [[tool]] (no /eprop/tools)")
        g = self.f["eprop/tools"]
        return {k: g[k][: self.steps] for k in g.keys()}

    def focus(self, k=-1):
        """Rest position of the point that moved most at output step k (where a load or a tool
        dents the organ), or None when nothing moved."""
        u = np.linalg.norm(self.field("displacement", k), axis=1)
        if not np.isfinite(u).all() or u.max() <= 0.0:
            return None
        return np.asarray(self.points[int(np.argmax(u))], dtype=float)

    def scenario(self):
        raw = self.f["eprop/scenario"][()]
        return bytes(np.asarray(raw, dtype=np.uint8)).decode("utf-8", "replace")

    def setting(self, section, key, default=None):
        """A scenario value, e.g. setting("material", "damping", 2.0)."""
        try:
            import tomllib
            return tomllib.loads(self.scenario()).get(section, {}).get(key, default)
        except Exception:
            return default

    def describe(self):
        """A few lines: steps, fields, loads, tools."""
        lines = [f"{self.path}: {self.n} points, {self.steps} complete output steps, "
                 f"t = {self.times[0]:.6g} .. {self.times[-1]:.6g}",
                 f"  fields  {', '.join(self.fields())}"]
        ld = self.loads()
        if len(ld["node"]):
            for l, node in enumerate(ld["node"]):
                f, u = ld["force"][-1, l], ld["displacement"][-1, l]
                lines.append(f"  load {l}  node {node}: |F| = {np.linalg.norm(f):.6g}, "
                             f"contact |u| = {np.linalg.norm(u):.6g} at the last step")
        else:
            lines.append("  loads   none (/eprop/probes/force is (steps, 0, 3))")
        if self.n_tools():
            t = self.tools()
            for i in range(self.n_tools()):
                lines.append(f"  tool {i}  |F| = {np.linalg.norm(t['force'][-1, i]):.6g}, "
                             f"indentation {t['indentation'][-1, i]:.6g}, "
                             f"{int(t['contact_nodes'][-1, i])} contact nodes at the last step")
        else:
            lines.append("  tools   none")
        return "\n".join(lines)


def main(argv):
    import argparse
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="eprop series (.h5)")
    a = ap.parse_args(argv)
    for path in a.files:
        with open_series(path) as s:
            print(s.describe())


if __name__ == "__main__":
    try:
        main(sys.argv[1:])
    except Fail as e:
        sys.exit(f"eprop_series.py: {e}")
