#!/usr/bin/env python3
"""Force against indentation of the tools of eprop runs (an indentation test).

The indentation is how deep the tool is below the undeformed organ along its path
(/eprop/tools/indentation: how far it must move back along its direction of motion to leave
the rest surface; negative while it approaches); the force is |F|, the force the tool exerts
on the organ (docs/tools.md: with the kinematic contact, the energy that flows out of the
nodes it holds; with law = "foundation", the foundation's pressures). A press, hold and retreat
draws the loading and the unloading branch. Tools are numbered from 1, as in the run's
summary. Axes are in metres, newtons and seconds for a run in the continuum reading, and in
the model's units for the paper's unit-free reading.

examples:
  force_indentation.py out/cylinder.h5 -o fi.png
  force_indentation.py soft.h5 stiff.h5 --tool 2 -o fi.png
Prints the path of the PNG."""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from eprop_series import Fail, open_series  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="eprop series (.h5) of runs with a [[tool]]")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    ap.add_argument("--tool", type=int, default=1, help="which tool, numbered from 1 as in the summary (default 1)")
    a = ap.parse_args()
    if a.tool < 1:
        raise Fail(f"--tool {a.tool}: tools are numbered from 1, as in the run's summary")
    k = a.tool - 1
    units = None
    fig, (ax, at) = plt.subplots(1, 2, figsize=(10, 4.2))
    ad = at.twinx()
    for path in a.files:
        s = open_series(path)
        t = s.tools()
        if k >= t["force"].shape[1]:
            raise Fail(f"{path}: no tool {a.tool} (the run has {t['force'].shape[1]})")
        depth = t["indentation"][:, k]
        force = np.linalg.norm(t["force"][:, k, :], axis=1)
        paper = str(s.setting("model", "reading", "continuum")).lower() == "paper"
        here = ("", "", "") if paper else (" (m)", " (N)", " (s)")
        units = here if units is None or units == here else ("", "", "")
        label = os.path.basename(path)
        ax.plot(depth, force, ".-", ms=3, label=label)
        line = at.plot(t["time"], force, label=f"{label}: |F|")[0]
        ad.plot(t["time"], depth, "--", lw=1, color=line.get_color(), label=f"{label}: indentation")
        s.close()
    lx, lf, lt = units or ("", "", "")
    ax.set_xlabel(f"indentation{lx}: the tool's depth below the undeformed surface")
    ax.set_ylabel(f"tool force |F|{lf}")
    ax.axvline(0.0, color="k", lw=0.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    at.set_xlabel(f"time{lt}")
    at.set_ylabel(f"tool force |F|{lf} (solid)")
    ad.set_ylabel(f"indentation{lx} (dashed)")
    at.grid(alpha=0.3)
    fig.suptitle(f"force against indentation, tool {a.tool}")
    fig.tight_layout()
    fig.savefig(a.output, dpi=120)
    print(a.output)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"force_indentation.py: {e}")
