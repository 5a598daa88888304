#!/usr/bin/env python3
"""Force-displacement curves of eprop runs (the paper's figure 5).

examples:
  force_displacement.py run.h5 -o fd.png               # |u_contact| against |F| over the run
  force_displacement.py g1_*.h5 g4_*.h5 --at-step 20 -o fig5.png
                                                        # one point per file at output step 20,
                                                        # curves grouped by the files' damping
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
    ap.add_argument("files", nargs="+", help="eprop series (.h5)")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    ap.add_argument("--load", type=int, default=0, help="which load (default 0)")
    ap.add_argument("--at-step", type=int, help="one point per file at this output step")
    a = ap.parse_args()
    fig, ax = plt.subplots(figsize=(6, 4.5))
    groups = {}
    iteration = None
    for path in a.files:
        s = open_series(path)
        force, disp = s.probes()
        if a.load >= force.shape[1]:
            raise Fail(f"{path}: no load {a.load} (the run has {force.shape[1]})")
        fm = np.linalg.norm(force[:, a.load, :], axis=1)
        um = np.linalg.norm(disp[:, a.load, :], axis=1)
        g = s.setting("material", "damping", 2.0)
        if a.at_step is None:
            ax.plot(fm, um, label=f"{os.path.basename(path)} (g = {g})")
        else:
            k = s.step_index(a.at_step)
            iteration = int(s.f["eprop/probes/step"][k])
            groups.setdefault(g, []).append((fm[k], um[k]))
        s.close()
    for g, pts in sorted(groups.items()):
        pts.sort()
        x, y = zip(*pts)
        ax.plot(x, y, "o-", label=f"g = {g}")
    ax.set_xlabel("applied force |F|")
    ax.set_ylabel("contact displacement |u|")
    title = "force-displacement" + (f" at iteration {iteration}" if a.at_step is not None else "")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(a.output, dpi=120)
    print(a.output)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"force_displacement.py: {e}")
