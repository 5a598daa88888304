#!/usr/bin/env python3
"""Measured against fitted curves of an `eprop fit` report (PREFIX.csv and PREFIX.json).

PREFIX.csv holds x, measured, fitted, residual (each parameter's sensitivity, and the curve's
number) per point; PREFIX.json the fitted parameters, the RMS residual and the curves
(docs/fit.md). One row of panels per curve: on the left the measured points and the fitted
curve, on the right the residuals. `eprop fit` calls this script itself when python3 has matplotlib.

examples:
  plot_fit.py press_fit -o press_fit.png
  plot_fit.py out/curve_fit           # writes out/curve_fit.png
Prints the path of the PNG."""
import argparse
import csv
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from eprop_series import Fail  # noqa: E402


def read_report(prefix):
    """(curve, x, measured, fitted, residual) arrays and the JSON report of PREFIX."""
    rows = []
    path = prefix + ".csv"
    try:
        with open(path, newline="") as f:
            r = csv.reader(f)
            header = next(r, None)
            if header is None or header[:4] != ["x", "measured", "fitted", "residual"]:
                raise Fail(f"{path}: not an eprop fit curve (header {header}); fix: give the PREFIX of `eprop fit -o PREFIX`")
            which = header.index("curve") if "curve" in header else None
            for k, row in enumerate(r, start=2):
                try:
                    rows.append([float(row[which]) if which is not None else 1.0] + [float(v) for v in row[:4]])
                except (ValueError, IndexError):
                    raise Fail(f"{path}:{k}: not four numbers and a curve; fix: write the report again with eprop fit")
    except FileNotFoundError:
        raise Fail(f"{path}: no such file; fix: give the PREFIX of `eprop fit -o PREFIX`")
    try:
        with open(prefix + ".json") as f:
            report = json.load(f)
    except FileNotFoundError:
        raise Fail(f"{prefix}.json: no such file; fix: give the PREFIX of `eprop fit -o PREFIX`")
    a = np.asarray(rows, dtype=float).reshape(-1, 5)
    return a[:, 0].astype(int), a[:, 1], a[:, 2], a[:, 3], a[:, 4], report


def number(v):
    """A number of the report; NaN for null (a figure the report could not give)."""
    return float("nan") if v is None else float(v)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("prefix", help="the PREFIX of `eprop fit -o PREFIX` (PREFIX.csv and PREFIX.json)")
    ap.add_argument("-o", "--output", help="PNG to write (default PREFIX.png)")
    a = ap.parse_args()
    curve, x, measured, fitted, residual, rep = read_report(a.prefix)
    out = a.output or a.prefix + ".png"
    ids = sorted(set(curve.tolist())) or [1]
    info = rep.get("curves") or [{}]
    fig, axes = plt.subplots(len(ids), 2, figsize=(10, 4.2 * len(ids)), squeeze=False)
    for row, c in enumerate(ids):
        ax, ar = axes[row]
        on = curve == c
        about = info[c - 1] if c - 1 < len(info) else {}
        # the report's values are in the scenario's units (SI in the continuum reading)
        xl = about.get("x", rep.get("x", "x"))
        yl = about.get("y", rep.get("y", "y"))
        ax.plot(x[on], measured[on], "o", ms=4, mfc="none", label="measured")
        ax.plot(x[on], fitted[on], "-", lw=1.5, label="fitted")
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        if len(ids) > 1:
            ax.set_title(f"curve {c}: {os.path.basename(about.get('data', ''))} (weight {about.get('weight', 1)})", fontsize=9)
        ar.axhline(0.0, color="k", lw=0.5)
        ar.plot(x[on], residual[on], ".-", ms=4)
        ar.set_xlabel(xl)
        ar.set_ylabel("fitted - measured")
        ar.grid(alpha=0.3)
        rms = about.get("rms", rep.get("rms"))
        rel = about.get("rms_relative", rep.get("rms_relative"))
        ar.set_title(f"rms {number(rms):.3g} ({number(rel):.2g} of {about.get('relative_to', rep.get('relative_to', 'the data range'))})", fontsize=9)
    params = ", ".join(f"{p['name']} = {number(p.get('value')):.4g}" for p in rep.get("parameters", []))
    fig.suptitle(f"eprop fit: {params}")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(out)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"plot_fit.py: {e}")
