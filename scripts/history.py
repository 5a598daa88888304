#!/usr/bin/env python3
"""Energy and displacement of an eprop run against time.

Draws the total energy sum_i V_i |phi_i|, the largest |u|, each load's contact |u| and each
tool's held-node |u| (with its force on a second axis) over the complete output steps. A run
without loads or tools shows the energy and the largest |u| only.

examples:
  history.py run.h5 -o history.png
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
    ap.add_argument("file", help="eprop series (.h5)")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    a = ap.parse_args()
    s = open_series(a.file)
    vol = s.control_volumes()
    energy, umax = [], []
    have = s.fields()
    for k in range(s.steps):
        # |phi| is the energy field; from the potential when only that was written
        e = s.field("energy", k) if "energy" in have else np.linalg.norm(s.field("potential", k), axis=1)
        energy.append(float(np.sum(vol * e)))
        umax.append(float(np.linalg.norm(s.field("displacement", k), axis=1).max()))
    _, disp = s.probes()
    tools = s.tools() if s.n_tools() else None
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6, 6), sharex=True)
    a1.plot(s.times, energy)
    a1.set_ylabel("sum V |phi|")
    a1.grid(alpha=0.3)
    a2.plot(s.times, umax, label="max |u|")
    nodes = s.loads()["node"]
    for l in range(disp.shape[1]):
        a2.plot(s.times, np.linalg.norm(disp[:, l, :], axis=1), "--", label=f"contact |u|, load {l} (node {nodes[l]})")
    if tools is not None:
        af = a2.twinx()
        for i in range(tools["force"].shape[1]):
            line = a2.plot(s.times, np.linalg.norm(tools["displacement"][:, i, :], axis=1), "-.",
                           label=f"held-node |u|, tool {i}")[0]
            af.plot(s.times, np.linalg.norm(tools["force"][:, i, :], axis=1), ":", color=line.get_color(),
                    label=f"|F|, tool {i}")
        af.set_ylabel("tool force |F| (dotted)")
    a2.set_xlabel("time")
    a2.set_ylabel("displacement")
    a2.grid(alpha=0.3)
    a2.legend(fontsize=8)
    fig.suptitle(os.path.basename(a.file))
    fig.tight_layout()
    fig.savefig(a.output, dpi=120)
    s.close()
    print(a.output)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"history.py: {e}")
