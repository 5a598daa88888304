#!/usr/bin/python3
"""Draws the finite-element reference of docs/validation.md (scripts/fe_reference.py's files):
(a) the force against the indentation, sphere and punch, centred and off-centre, the part a fit
may use (filled) and the held-out part (open); (b) uz and (c) ux along x on the top face through
the indentation point at 3 and 6 mm.

example: fe_reference_plot.py scenarios/validation/reference -o docs/validation_reference.png"""
import argparse
import csv
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def rows(path):
    with open(path, newline="") as f:
        r = list(csv.reader(f))
    return r[0], r[1:]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("reference", help="the reference directory (fe_reference.py --out-dir)")
    ap.add_argument("-o", "--output", required=True, help="the figure (.png)")
    a = ap.parse_args()
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    colours = {"sphere": "tab:blue", "punch": "tab:red"}
    for tool in ("sphere", "punch"):
        for pos, style in (("centre", "-"), ("offcentre", "--")):
            p = os.path.join(a.reference, f"force_{tool}_{pos}.csv")
            if not os.path.exists(p):
                continue
            _, r = rows(p)
            d = [float(x[0]) * 1e3 for x in r]
            F = [float(x[1]) for x in r]
            fit = [x[3] == "fit" for x in r]
            c = colours[tool]
            ax[0].plot(d, F, style, color=c, label=f"{tool}, {pos}")
            ax[0].plot([v for v, k in zip(d, fit) if k], [v for v, k in zip(F, fit) if k], "o", color=c)
            ax[0].plot([v for v, k in zip(d, fit) if not k], [v for v, k in zip(F, fit) if not k], "o",
                       color=c, mfc="none")
            _, L = rows(os.path.join(a.reference, f"lines_{tool}_{pos}.csv"))
            for depth, alpha in ((0.003, 0.5), (0.006, 1.0)):
                s = [x for x in L if abs(float(x[0]) - depth) < 1e-12 and x[1] == "surface"]
                x = [float(v[2]) * 1e3 for v in s]
                ax[1].plot(x, [float(v[7]) * 1e3 for v in s], style, color=c, alpha=alpha,
                           label=f"{tool}, {pos}, {depth * 1e3:g} mm")
                ax[2].plot(x, [float(v[5]) * 1e3 for v in s], style, color=c, alpha=alpha)
    ax[0].set_xlabel("indentation (mm)")
    ax[0].set_ylabel("force (N)")
    ax[0].set_title("force (filled: fit, open: held out)")
    ax[0].legend()
    ax[1].set_xlabel("x on the top face, y = 20 mm (mm)")
    ax[1].set_ylabel("uz (mm)")
    ax[1].set_title("top face: uz at 3 mm (light) and 6 mm")
    ax[1].legend(fontsize=7)
    ax[2].set_xlabel("x on the top face, y = 20 mm (mm)")
    ax[2].set_ylabel("ux (mm)")
    ax[2].set_title("top face: ux at 3 mm (light) and 6 mm")
    for x in ax:
        x.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(a.output, dpi=110)
    print(a.output)


if __name__ == "__main__":
    main()
