#!/usr/bin/env python3
"""Measured against fitted curve of an `eprop fit` report (PREFIX.csv and PREFIX.json).

PREFIX.csv holds x, measured, fitted, residual (and each parameter's sensitivity) per point; PREFIX.json the fitted parameters and
the RMS residual (docs/fit.md). The left panel draws the measured points and the fitted curve,
the right one the residuals. `eprop fit` calls this script itself when python3 has matplotlib.

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
    """(x, measured, fitted, residual) arrays and the JSON report of PREFIX."""
    rows = []
    path = prefix + ".csv"
    try:
        with open(path, newline="") as f:
            r = csv.reader(f)
            header = next(r, None)
            if header is None or header[:4] != ["x", "measured", "fitted", "residual"]:
                raise Fail(f"{path}: not an eprop fit curve (header {header}); fix: give the PREFIX of `eprop fit -o PREFIX`")
            for k, row in enumerate(r, start=2):
                try:
                    rows.append([float(v) for v in row[:4]])
                except ValueError:
                    raise Fail(f"{path}:{k}: not four numbers; fix: write the report again with eprop fit")
    except FileNotFoundError:
        raise Fail(f"{path}: no such file; fix: give the PREFIX of `eprop fit -o PREFIX`")
    try:
        with open(prefix + ".json") as f:
            report = json.load(f)
    except FileNotFoundError:
        raise Fail(f"{prefix}.json: no such file; fix: give the PREFIX of `eprop fit -o PREFIX`")
    a = np.asarray(rows, dtype=float).reshape(-1, 4)
    return a[:, 0], a[:, 1], a[:, 2], a[:, 3], report


def number(v):
    """A number of the report; NaN for null (a figure the report could not give)."""
    return float("nan") if v is None else float(v)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("prefix", help="the PREFIX of `eprop fit -o PREFIX` (PREFIX.csv and PREFIX.json)")
    ap.add_argument("-o", "--output", help="PNG to write (default PREFIX.png)")
    a = ap.parse_args()
    x, measured, fitted, residual, rep = read_report(a.prefix)
    out = a.output or a.prefix + ".png"
    fig, (ax, ar) = plt.subplots(1, 2, figsize=(10, 4.2))
    ax.plot(x, measured, "o", ms=4, mfc="none", label="measured")
    ax.plot(x, fitted, "-", lw=1.5, label="fitted")
    ax.set_xlabel(rep.get("x", "x"))
    ax.set_ylabel(rep.get("y", "y"))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ar.axhline(0.0, color="k", lw=0.5)
    ar.plot(x, residual, ".-", ms=4)
    ar.set_xlabel(rep.get("x", "x"))
    ar.set_ylabel("fitted - measured")
    ar.grid(alpha=0.3)
    params = ", ".join(f"{p['name']} = {number(p.get('value')):.4g}" for p in rep.get("parameters", []))
    ar.set_title(f"rms {number(rep.get('rms')):.3g} ({number(rep.get('rms_relative')):.2g} of {rep.get('relative_to', 'the data range')})", fontsize=9)
    fig.suptitle(f"eprop fit: {params}")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(out)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"plot_fit.py: {e}")
