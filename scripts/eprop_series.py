"""Reading eprop's VTKHDF series: the pieces the post-processing scripts share.

A file from a running or killed job may hold more rows than complete steps: only the
`/eprop` `steps_complete` steps are read. Opening retries briefly while the writer flushes.
"""
import time

import h5py
import numpy as np


class Fail(Exception):
    """An error reported to the user as a one-line message."""


def open_series(path, tries=50):
    last = None
    for _ in range(tries):
        try:
            f = h5py.File(path, "r")
            if "eprop" not in f or "VTKHDF" not in f:
                f.close()
                raise Fail(f"{path}: not an eprop series (no /VTKHDF or /eprop group)")
            return Series(path, f)
        except FileNotFoundError:
            raise Fail(f"{path}: no such file")
        except OSError as e:  # the writer is flushing, or the file is damaged
            last = e
            time.sleep(0.05)
    raise Fail(f"{path}: cannot open: {last}")


class Series:
    def __init__(self, path, f):
        self.path, self.f = path, f
        self.n = int(f["VTKHDF/NumberOfPoints"][0])
        self.steps = int(f["eprop"].attrs["steps_complete"])
        if self.steps < 1:
            raise Fail(f"{path}: no complete output step yet")
        self.times = f["VTKHDF/Steps/Values"][: self.steps]
        self.points = f["VTKHDF/Points"][:]

    def close(self):
        self.f.close()

    def step_index(self, k):
        kk = k + self.steps if k < 0 else k
        if not 0 <= kk < self.steps:
            raise Fail(f"{self.path}: output step {k} is not in the file ({self.steps} complete steps)")
        return kk

    def field(self, name, k):
        if f"VTKHDF/PointData/{name}" not in self.f:
            have = ", ".join(self.f["VTKHDF/PointData"].keys())
            raise Fail(f"{self.path}: no field `{name}` (the file has: {have})")
        k = self.step_index(k)
        return np.asarray(self.f[f"VTKHDF/PointData/{name}"][k * self.n:(k + 1) * self.n], dtype=float)

    def cells(self):
        return (self.f["VTKHDF/Connectivity"][:], self.f["VTKHDF/Offsets"][:], self.f["VTKHDF/Types"][:])

    def control_volumes(self):
        return self.f["eprop/control_volumes"][:]

    def probes(self):
        """(force (S, L, 3), displacement (S, L, 3)) of the complete steps."""
        p = self.f["eprop/probes"]
        return p["force"][: self.steps], p["displacement"][: self.steps]

    def tools(self):
        """Per tool, over the complete steps: dict of time (S,), position, force, displacement
        (S, T, 3), contact_nodes, contact_area, indentation (S, T)."""
        if "eprop/tools" not in self.f:
            raise Fail(f"{self.path}: the run has no [[tool]] (no /eprop/tools)")
        g = self.f["eprop/tools"]
        return {k: g[k][: self.steps] for k in g.keys()}

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
