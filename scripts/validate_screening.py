#!/usr/bin/env python3
"""The screening's fit and predictions against the finite-element reference (docs/validation.md,
"The screening"). OUT holds none/ (no screening) and l<L>/ ([model] screening = L) with the
presses of scripts/validate_screening.sh: {sphere,punch}_{centre,offcentre}.h5.

The fit uses the shallow half only (the reference's `set` = fit: depths <= 3 mm of the centred
presses): the screening length by the displacement of the top face along the reference's two
surface lines (pooled relative RMS error over both tools; young does not move the tissue under a
prescribed tool, so l is fitted alone), then young per tool by least squares on the force to
3 mm (the kinematic contact's force is proportional to young, so the least-squares young is
young0 sum(F_ref F) / sum(F^2), what `eprop fit --param young` converges to). Everything else is
predicted: the forces to 6 mm and off-centre, the top face's displacement at 3 and 6 mm (the
held-out grids) and the lines below the surface.

usage: validate_screening.py OUT L [L ...]  (prints the tables; OUT/screening.png)"""
import csv
import os
import sys

import h5py
import numpy as np
from scipy.interpolate import LinearNDInterpolator, griddata

REF = os.path.join(os.path.dirname(__file__), "..", "scenarios", "validation", "reference")
YOUNG0 = 5000.0
DEPTHS = (0.5, 1, 2, 3, 4, 5, 6)


def load(path):
    f = h5py.File(path, "r")
    return {
        "P": f["VTKHDF/Points"][:],
        "n": int(f["VTKHDF/NumberOfPoints"][0]),
        "t": f["eprop/tools/time"][:],
        "d": f["eprop/tools/indentation"][:, 0],
        "F": -f["eprop/tools/force"][:, 0, 2],
        "f": f,
    }


def displacement(run, depth_mm):
    """u at the output step of the tool's depth (1 mm/s from first touch: t = depth)."""
    k = int(np.argmin(abs(run["t"] - depth_mm)))
    if abs(run["t"][k] - depth_mm) > 1e-6:
        return None
    f = run["f"]
    o = f["VTKHDF/Steps/PointDataOffsets/displacement"][k]
    return f["VTKHDF/PointData/displacement"][o : o + run["n"]]


def ref_force(tool, pos):
    rows = csv.DictReader(open(os.path.join(REF, f"force_{tool}_{pos}.csv")))
    return {round(float(r["indentation_m"]) * 1e3, 3): float(r["force_N"]) for r in rows}


def lines_error(run, tool, pos, names, sets):
    rows = [
        r
        for r in csv.DictReader(open(os.path.join(REF, f"lines_{tool}_{pos}.csv")))
        if r["set"] in sets and r["line"] in names
    ]
    num = den = 0.0
    for d in sorted({float(r["depth_m"]) for r in rows}):
        u = displacement(run, d * 1e3)
        if u is None:
            continue
        it = LinearNDInterpolator(run["P"], u)
        rr = [r for r in rows if float(r["depth_m"]) == d]
        x = np.array([[float(r[c]) for c in "xyz"] for r in rr])
        fe = np.array([[float(r[c]) for c in ("ux", "uy", "uz")] for r in rr])
        m = it(x)
        ok = ~np.isnan(m[:, 0])
        num += np.sum((m[ok] - fe[ok]) ** 2)
        den += np.sum(fe[ok] ** 2)
    return np.sqrt(num / den) if den > 0 else float("nan")


def surface(run, tool, pos, mm):
    g = np.array(
        [[float(v) for v in r.values()] for r in csv.DictReader(open(os.path.join(REF, f"surface_{tool}_{pos}_{mm}mm.csv")))]
    )
    u = displacement(run, mm)
    top = np.abs(run["P"][:, 2] - 0.02) < 1e-9
    ours = np.stack([griddata(run["P"][top][:, :2], u[top][:, q], g[:, :2], method="linear") for q in range(3)], 1)
    fe = g[:, 2:5]
    rms = np.sqrt(np.mean(np.sum(fe**2, 1)))
    err = np.sqrt(np.mean(np.sum((ours - fe) ** 2, 1))) / rms
    errz = np.sqrt(np.mean((ours[:, 2] - fe[:, 2]) ** 2)) / rms
    return err, errz, g, ours


def main():
    out, lengths = sys.argv[1], sys.argv[2:]
    dirs = [("none", os.path.join(out, "none"))] + [(f"l = {float(l) * 1e3:g} mm", os.path.join(out, f"l{l}")) for l in lengths]
    print("## the fit of l: the top face along the surface lines, depths <= 3 mm (relative RMS error)")
    print("| screening | sphere | punch | pooled (mean) | vertical line, sphere / punch | mid-depth line, sphere / punch |")
    print("|---|---|---|---|---|---|")
    for name, d in dirs:
        runs = {t: load(os.path.join(d, f"{t}_centre.h5")) for t in ("sphere", "punch")}
        s = [lines_error(runs[t], t, "centre", ("surface", "surface_y"), ("fit",)) for t in ("sphere", "punch")]
        v = [lines_error(runs[t], t, "centre", ("vertical",), ("fit",)) for t in ("sphere", "punch")]
        m = [lines_error(runs[t], t, "centre", ("middepth",), ("fit",)) for t in ("sphere", "punch")]
        print(f"| {name} | {s[0]:.3f} | {s[1]:.3f} | {np.mean(s):.3f} | {v[0]:.3f} / {v[1]:.3f} | {m[0]:.3f} / {m[1]:.3f} |")
    figure = {}
    for name, d in dirs:
        if not all(os.path.exists(os.path.join(d, f"{t}_{p}.h5")) for t in ("sphere", "punch") for p in ("centre", "offcentre")):
            continue
        runs = {(t, p): load(os.path.join(d, f"{t}_{p}.h5")) for t in ("sphere", "punch") for p in ("centre", "offcentre")}
        if runs[("sphere", "centre")]["t"].max() < 6 - 1e-9:
            continue
        print(f"\n## {name}: young fitted on the force to 3 mm, predictions")
        print("| press | young (kPa) | F / F_FE at " + " / ".join(f"{x:g}" for x in DEPTHS) + " mm | profile 3 mm (uz only) | profile 6 mm (uz only) |")
        print("|---|---|---|---|---|")
        for t in ("sphere", "punch"):
            rc = runs[(t, "centre")]
            fr = ref_force(t, "centre")
            xs = [x for x in DEPTHS if x <= 3]
            model = np.array([np.interp(x * 1e-3, rc["d"], rc["F"]) for x in xs])
            refv = np.array([fr[x] for x in xs])
            young = YOUNG0 * np.sum(refv * model) / np.sum(model**2)
            for p in ("centre", "offcentre"):
                r = runs[(t, p)]
                frp = ref_force(t, p)
                ratio = [young / YOUNG0 * np.interp(x * 1e-3, r["d"], r["F"]) / frp[x] for x in DEPTHS]
                e3, z3, _, _ = surface(r, t, p, 3)
                e6, z6, g, ours = surface(r, t, p, 6)
                figure[(name, t, p)] = (r, young, g, ours)
                print(
                    f"| {t} {p} | {young / 1e3:.2f} | "
                    + " / ".join(f"{v:.3f}" for v in ratio)
                    + f" | {e3:.3f} ({z3:.3f}) | {e6:.3f} ({z6:.3f}) |"
                )
            off = [np.interp(x * 1e-3, runs[(t, "offcentre")]["d"], runs[(t, "offcentre")]["F"]) / np.interp(x * 1e-3, rc["d"], rc["F"]) - 1 for x in (1, 3, 6)]
            print(f"|   {t}: off-centre against centred at 1 / 3 / 6 mm | | " + " / ".join(f"{100 * v:+.1f} %" for v in off) + " | | |")
        for t in ("sphere", "punch"):
            for lines in (("vertical",), ("middepth",)):
                e = lines_error(runs[(t, "centre")], t, "centre", lines, ("heldout",))
                print(f"|   {t} {lines[0]} line, 4-6 mm (held out) | | relative RMS error {e:.3f} | | |")
    plot(out, figure)


def plot(out, figure):
    if not figure:
        return  # the fit's presses only (SCAN=1): nothing predicted to draw
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    names = sorted({k[0] for k in figure}, key=lambda n: n != "none")
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    for j, t in enumerate(("sphere", "punch")):
        a = ax[0, j]
        for p, mk in (("centre", "o"), ("offcentre", "s")):
            fr = ref_force(t, p)
            a.plot(list(fr), list(fr.values()), mk, mfc="none", color="k", label=f"FE, {p}")
            for name in names:
                r, young, _, _ = figure[(name, t, p)]
                ls = "-" if p == "centre" else "--"
                a.plot(r["d"] * 1e3, young / YOUNG0 * r["F"], ls, label=f"eprop {name} (young {young / 1e3:.2f} kPa), {p}")
        a.axvline(3, color="0.7", lw=0.8)
        a.set_xlabel("indentation (mm)")
        a.set_ylabel("force (N)")
        a.set_title(f"{t}: fitted to 3 mm, predicted beyond and off-centre")
        a.legend(fontsize=6)
        a = ax[1, j]
        first = True
        for name in names:
            r, _, g, ours = figure[(name, t, "centre")]
            sel = np.abs(g[:, 1] - 0.02) < 1e-9
            if first:
                a.plot(g[sel, 0] * 1e3, g[sel, 4] * 1e3, "k.", label="FE uz")
                a.plot(g[sel, 0] * 1e3, g[sel, 2] * 1e3, "k+", label="FE ux")
                first = False
            a.plot(g[sel, 0] * 1e3, ours[sel, 2] * 1e3, "-", label=f"eprop {name} uz")
            a.plot(g[sel, 0] * 1e3, ours[sel, 0] * 1e3, ":", label=f"eprop {name} ux")
        a.set_xlabel("x on the top face, y = 20 mm (mm)")
        a.set_ylabel("displacement at 6 mm (mm)")
        a.set_title(f"{t}, centred, 6 mm deep (held out)")
        a.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "screening.png"), dpi=110)


if __name__ == "__main__":
    main()
