#!/usr/bin/env python3
"""Force-displacement curves of eprop runs (the paper's figure 5).

The force is a [[load]]'s applied force and the displacement its contact node's (or patch's);
with --tool T (and by default in a run with tools but no loads) the tool's force on the organ and
the mean displacement of the nodes it holds. A run with neither is an error.

examples:
  force_displacement.py run.h5 -o fd.png               # |u_contact| against |F| over the run
  force_displacement.py g1_*.h5 g4_*.h5 --at-step 20 -o fig5.png
                                                        # one point per file at output step 20,
                                                        # curves grouped by the files' damping
  force_displacement.py out/cylinder.h5 --tool 0 -o fd.png   # a tool run (the demo)
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


def curve(s, a):
    """(|F| (S,), |u| (S,), label) of the load or tool chosen by the options."""
    nl, nt = s.n_loads(), s.n_tools()
    tool = a.tool
    if tool is None and a.load is None and nl == 0:
        if nt == 0:
            raise Fail(f"{s.path}: the run has no [[load]] and no [[tool]]: no force to plot")
        tool = 0
    if tool is not None:
        if tool >= nt:
            raise Fail(f"{s.path}: no tool {tool} (the run has {nt} [[tool]])")
        t = s.tools()
        return (np.linalg.norm(t["force"][:, tool, :], axis=1),
                np.linalg.norm(t["displacement"][:, tool, :], axis=1), f"tool {tool}")
    load = a.load or 0
    if load >= nl:
        more = f"; its tools: --tool 0..{nt - 1}" if nt else ""
        raise Fail(f"{s.path}: no load {load} (the run has {nl} [[load]]{more})")
    force, disp = s.probes()
    return (np.linalg.norm(force[:, load, :], axis=1), np.linalg.norm(disp[:, load, :], axis=1),
            f"load {load}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="eprop series (.h5)")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    ap.add_argument("--load", type=int, help="which load (default 0)")
    ap.add_argument("--tool", type=int, help="a tool instead of a load (default: tool 0 when the run has no loads)")
    ap.add_argument("--at-step", type=int, help="one point per file at this output step")
    a = ap.parse_args()
    if a.load is not None and a.tool is not None:
        raise Fail("give --load or --tool, not both")
    fig, ax = plt.subplots(figsize=(6, 4.5))
    groups = {}
    iteration = None
    what = set()
    for path in a.files:
        with open_series(path) as s:
            fm, um, which = curve(s, a)
            what.add(which)
            g = s.setting("material", "damping", 2.0)
            if a.at_step is None:
                ax.plot(fm, um, label=f"{os.path.basename(path)} {which} (g = {g})")
            else:
                k = s.step_index(a.at_step)
                iteration = int(s.solver_steps()[k])
                groups.setdefault(g, []).append((fm[k], um[k]))
    for g, pts in sorted(groups.items()):
        pts.sort()
        x, y = zip(*pts)
        ax.plot(x, y, "o-", label=f"g = {g}")
    tools = all(w.startswith("tool") for w in what)
    ax.set_xlabel("tool force |F|" if tools else "applied force |F|")
    ax.set_ylabel("mean displacement of the held nodes |u|" if tools else "contact displacement |u|")
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
