#!/usr/bin/env python3
"""Energy and displacement of an eprop run against time.

Draws the total energy sum_i V_i |phi_i|, the largest |u| and each load's contact |u| over the
complete output steps.

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
    for k in range(s.steps):
        phi = s.field("potential", k)
        energy.append(float(np.sum(vol * np.linalg.norm(phi, axis=1))))
        umax.append(float(np.linalg.norm(s.field("displacement", k), axis=1).max()))
    _, disp = s.probes()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(6, 6), sharex=True)
    a1.plot(s.times, energy)
    a1.set_ylabel("sum V |phi|")
    a1.grid(alpha=0.3)
    a2.plot(s.times, umax, label="max |u|")
    for l in range(disp.shape[1]):
        a2.plot(s.times, np.linalg.norm(disp[:, l, :], axis=1), "--", label=f"contact |u|, load {l}")
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
