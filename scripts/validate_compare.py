#!/usr/bin/env python3
"""Compares an eprop sphere press of the validation block with the finite-element reference
(docs/validation.md, scripts/fe_reference.py) and writes CSV tables.

The indentation of both is the sphere's travel below the undeformed top face: for eprop it is
computed from the tool's position, (z_top + R) - p_z, with z_top the highest mesh point and R
the tool's radius, so it does not depend on how eprop reports /eprop/tools/indentation.
The force is the tool's vertical force on the block. --length and --force give eprop's units
in metres and newtons: 1 and 1 for the validation scenarios (the continuum reading, SI units);
a scenario of the paper reading read in mm needs --length 1e-3 and its force has no unit.

Writes into --out-dir:
  force.csv   indentation_m, force_fe_N, force_eprop_N, ratio, set (fit: the centred press to
              4 mm, the part a fit may use; predict: the deeper and the off-centre press)
  lines.csv   depth_m, eprop_depth_m, line, x, y, z, ux_fe, uz_fe, ux_eprop, uz_eprop: the
              displacement along the reference's lines at the eprop nodes on them, at the eprop
              output step nearest each reference depth (metres)
  summary.csv per depth and line: RMS of the FE uz, RMS of the difference, points

examples:
  validate_compare.py out/validation/centre.h5 --reference scenarios/validation/reference \\
      --length 1 -o out/validation"""
import argparse
import csv
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
from eprop_series import Fail, open_series  # noqa: E402


def read_csv(path):
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    return rows[0], rows[1:]


def force_table(ref, case):
    out = []
    # the centred press to 4 mm is what a fit may use; the rest is predicted
    names = [(f"force_{case}.csv", "fit" if case == "centre" else "predict"),
             (f"force_{case}_deep.csv", "predict")]
    for name, tag in names:
        p = os.path.join(ref, name)
        if not os.path.exists(p):
            continue
        _, rows = read_csv(p)
        out += [(float(r[0]), float(r[1]), tag) for r in rows]
    if not out:
        raise Fail(f"{ref}: no force_{case}.csv; fix: run scripts/fe_reference.py (or scripts/validate.sh)")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("series", help="eprop series (.h5) of the press")
    ap.add_argument("--reference", required=True, help="the reference directory (fe_reference.py --out-dir)")
    ap.add_argument("--case", default="centre", choices=["centre", "offcentre"])
    ap.add_argument("--length", type=float, default=1.0, help="eprop's length unit in metres (mm: 1e-3)")
    ap.add_argument("--force", type=float, default=1.0, help="eprop's force unit in newtons")
    ap.add_argument("--tool", type=int, default=0)
    ap.add_argument("-o", "--out-dir", required=True)
    a = ap.parse_args()
    os.makedirs(a.out_dir, exist_ok=True)
    s = open_series(a.series)
    t = s.tools()
    try:
        import tomllib
        radius = float(tomllib.loads(s.scenario())["tool"][a.tool]["radius"])
    except Exception:
        radius = None
    if radius is None:
        raise Fail(f"{a.series}: no radius of [[tool]] {a.tool + 1} in the recorded scenario")
    ztop = float(s.points[:, 2].max())
    depth = ((ztop + radius) - t["position"][:, a.tool, 2]) * a.length
    force = -t["force"][:, a.tool, 2] * a.force  # the block is pushed down: -F_z >= 0
    order = np.argsort(depth)
    fe = force_table(a.reference, a.case)
    with open(os.path.join(a.out_dir, "force.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["indentation_m", "force_fe_N", "force_eprop_N", "ratio", "set"])
        for d, F, tag in fe:
            if d > depth.max() or d < depth.min():
                fe_e = float("nan")
            else:
                fe_e = float(np.interp(d, depth[order], force[order]))
            w.writerow([f"{d:.6g}", f"{F:.9g}", f"{fe_e:.9g}", f"{fe_e / F:.6g}", tag])

    # displacement along the lines, at the eprop nodes on them
    _, rows = read_csv(os.path.join(a.reference, f"lines_{a.case}.csv"))
    pts = s.points * a.length
    h = np.sort(np.unique(np.round(pts[:, 0], 9)))
    tol = 1e-3 * (np.diff(h).min() if len(h) > 1 else 1.0)
    lines_out, summary = [], []
    by = {}
    for r in rows:
        by.setdefault((float(r[0]), r[1]), []).append([float(v) for v in r[2:]])
    for (d, name), vals in sorted(by.items()):
        v = np.array(vals)
        k = int(np.argmin(np.abs(depth - d)))
        u = s.field("displacement", k) * a.length
        if name == "vertical":
            axis, fixed = 2, (0, 1)
        else:
            axis, fixed = 0, (1, 2)
        on = np.ones(len(pts), bool)
        for c in fixed:
            on &= np.abs(pts[:, c] - v[0, c]) < tol
        idx = np.where(on)[0]
        idx = idx[np.argsort(pts[idx, axis])]
        if len(idx) == 0:
            continue
        fe_ux = np.interp(pts[idx, axis], v[:, axis], v[:, 3])
        fe_uz = np.interp(pts[idx, axis], v[:, axis], v[:, 5])
        for i, j in enumerate(idx):
            lines_out.append([f"{d:.6g}", f"{depth[k]:.6g}", name] + [f"{x:.6g}" for x in pts[j]] +
                             [f"{fe_ux[i]:.7g}", f"{fe_uz[i]:.7g}", f"{u[j, 0]:.7g}", f"{u[j, 2]:.7g}"])
        diff = u[idx, 2] - fe_uz
        summary.append([f"{d:.6g}", f"{depth[k]:.6g}", name, f"{np.sqrt(np.mean(fe_uz**2)):.6g}",
                        f"{np.sqrt(np.mean(diff**2)):.6g}", len(idx)])
    with open(os.path.join(a.out_dir, "lines.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["depth_m", "eprop_depth_m", "line", "x", "y", "z", "ux_fe", "uz_fe", "ux_eprop", "uz_eprop"])
        w.writerows(lines_out)
    with open(os.path.join(a.out_dir, "summary.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["depth_m", "eprop_depth_m", "line", "rms_uz_fe_m", "rms_uz_difference_m", "points"])
        w.writerows(summary)
    s.close()
    for n in ("force.csv", "lines.csv", "summary.csv"):
        print(os.path.join(a.out_dir, n))


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"validate_compare.py: {e}")
