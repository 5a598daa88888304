#!/usr/bin/env python3
"""Draws the validation figure of docs/validation.md from the tables of scripts/validate.sh:
(a) the force against the indentation, the finite-element reference against eprop, for the
centred press (the part to 4 mm fitted, 4 to 6 mm predicted) and the off-centre press
(predicted); (b) uz along the vertical line under the indenter and along the surface line, at
2 and 4 mm (predicted).

usage: validate_plot.py OUT -o docs/validation_force.png   (OUT: scripts/validate.sh's directory)"""
import argparse
import csv
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", help="the directory scripts/validate.sh wrote")
    ap.add_argument("-o", "--output", required=True, help="PNG")
    a = ap.parse_args()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 3.6), dpi=90)
    for case, colour in (("centre", "C0"), ("offcentre", "C1")):
        r = rows(os.path.join(a.out, case, "force.csv"))
        d = [float(x["indentation_m"]) * 1e3 for x in r]
        fe = [float(x["force_fe_N"]) for x in r]
        ep = [float(x["force_eprop_N"]) for x in r]
        fit = [x["set"] == "fit" for x in r]
        ax.plot(d, fe, "o", color=colour, mfc="none", label=f"reference, {case}")
        fd = [v for v, f in zip(d, fit) if f]
        pd = [v for v, f in zip(d, fit) if not f]
        if fd:
            ax.plot(fd, [v for v, f in zip(ep, fit) if f], "-", color=colour, lw=2, label="eprop, fitted")
        # the predicted part joins the fitted one at its last point
        k = len(fd) - 1 if fd else 0
        ax.plot(([fd[-1]] if fd else []) + pd, ([ep[k]] if fd else []) + [v for v, f in zip(ep, fit) if not f],
                "--", color=colour, lw=2, label=f"eprop, predicted ({case})")
    ax.axvline(4.0, color="0.7", lw=0.8)
    ax.set_xlabel("indentation (mm)")
    ax.set_ylabel("force (N)")
    ax.set_title("force against indentation")
    ax.legend(fontsize=7)
    r = rows(os.path.join(a.out, "centre", "lines.csv"))
    for depth, style in ((2e-3, "C2"), (4e-3, "C3")):
        for line, marker in (("vertical", "o"), ("surface", "s")):
            p = [x for x in r if abs(float(x["depth_m"]) - depth) < 1e-9 and x["line"] == line]
            if not p:
                continue
            key = "z" if line == "vertical" else "x"
            s = [float(x[key]) * 1e3 for x in p]
            bx.plot(s, [float(x["uz_fe"]) * 1e3 for x in p], marker, color=style, mfc="none", ms=4,
                    label=f"reference {line}, {depth * 1e3:g} mm")
            bx.plot(s, [float(x["uz_eprop"]) * 1e3 for x in p], "-" if line == "vertical" else ":",
                    color=style, label=f"eprop {line}, {depth * 1e3:g} mm")
    bx.set_xlabel("z on the vertical line, x on the surface line (mm)")
    bx.set_ylabel("uz (mm)")
    bx.set_title("displacement, centred press (predicted)")
    bx.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(a.output)
    print(a.output)


if __name__ == "__main__":
    main()
