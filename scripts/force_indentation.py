#!/usr/bin/env python3
"""Force against indentation of the tools of eprop runs (an indentation test).

The indentation is how deep the tool is below the undeformed organ along its path
(/eprop/tools/indentation: how far it must move back along its direction of motion to leave
the rest surface; negative while it approaches); the force is |F|, the force the tool exerts
on the organ (the elastic foundation's pressures on the rest surface, docs/tools.md). A
press, hold and retreat draws the loading and the unloading branch.

examples:
  force_indentation.py out/cylinder.h5 -o fi.png
  force_indentation.py soft.h5 stiff.h5 --tool 1 -o fi.png
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
    ap.add_argument("--tool", type=int, default=0, help="which tool (default 0)")
    a = ap.parse_args()
    fig, (ax, at) = plt.subplots(1, 2, figsize=(10, 4.2))
    ad = at.twinx()
    for path in a.files:
        s = open_series(path)
        t = s.tools()
        if a.tool >= t["force"].shape[1]:
            raise Fail(f"{path}: no tool {a.tool} (the run has {t['force'].shape[1]})")
        depth = t["indentation"][:, a.tool]
        force = np.linalg.norm(t["force"][:, a.tool, :], axis=1)
        label = os.path.basename(path)
        ax.plot(depth, force, ".-", ms=3, label=label)
        line = at.plot(t["time"], force, label=f"{label}: |F|")[0]
        ad.plot(t["time"], depth, "--", lw=1, color=line.get_color(), label=f"{label}: indentation")
        s.close()
    ax.set_xlabel("indentation (depth of the tool below the undeformed surface, along its path)")
    ax.set_ylabel("tool force |F|")
    ax.axvline(0.0, color="k", lw=0.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    at.set_xlabel("time")
    at.set_ylabel("tool force |F| (solid)")
    ad.set_ylabel("indentation (dashed)")
    at.grid(alpha=0.3)
    fig.suptitle(f"force-indentation, tool {a.tool}")
    fig.tight_layout()
    fig.savefig(a.output, dpi=120)
    print(a.output)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"force_indentation.py: {e}")
