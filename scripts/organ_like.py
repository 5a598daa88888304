#!/usr/bin/env python3
"""Write an organ-like closed surface (a kidney-shaped bean, in mm) as an OFF file, for tetgen.

A subdivided icosahedron is pushed in on its -x side (the hilum) and stretched to the size
given; the surface is closed, consistently oriented (outward normals) and free of
self-intersections (a radial map of a sphere), so `tetgen -pq` meshes its volume. Plain Python:
no packages needed.

examples:
  organ_like.py -o kidney.off                         # 1,280 triangles, 110 x 60 x 45 mm
  organ_like.py -o kidney.off --refine 3 --size 110,60,45
  tetgen -pq1.4 -Q kidney.off                         # -> kidney.1.node, kidney.1.ele, kidney.1.face
Prints the path of the OFF file."""
import argparse
import math
import os
import sys


def icosphere(refine):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    v = [tuple(c / math.sqrt(sum(x * x for x in p)) for c in p) for p in v]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
         (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5),
         (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(refine):
        mid = {}

        def m(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = [(x + y) / 2 for x, y in zip(v[a], v[b])]
                n = math.sqrt(sum(x * x for x in p))
                v.append(tuple(x / n for x in p))
                mid[key] = len(v) - 1
            return mid[key]

        f = [g for a, b, c in f for g in ((a, m(a, b), m(a, c)), (b, m(b, c), m(a, b)),
                                             (c, m(a, c), m(b, c)), (m(a, b), m(b, c), m(a, c)))]
    return v, f


def bean(p, depth):
    """The unit-sphere point p moved radially: pushed in around -x (the hilum)."""
    x, y, z = p
    r = 1.0 - depth * max(0.0, -x) ** 2 * math.exp(-(y * y) / 0.3 - (z * z) / 0.5)
    return (r * x, r * y, r * z)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", required=True, help="OFF file to write")
    ap.add_argument("--refine", type=int, default=3, help="subdivisions of the icosahedron (default 3: 1,280 triangles)")
    ap.add_argument("--size", default="110,60,45", help="extent along y, x and z in mm (default 110,60,45)")
    ap.add_argument("--depth", type=float, default=0.45, help="how deep the hilum is pushed in, 0..0.9 (default 0.45)")
    a = ap.parse_args()
    try:
        ly, lx, lz = (float(s) for s in a.size.split(","))
    except ValueError:
        sys.exit(f"organ_like.py: --size {a.size}: give three lengths, e.g. 110,60,45")
    if not (0 <= a.refine <= 6 and 0.0 <= a.depth <= 0.9 and min(lx, ly, lz) > 0):
        sys.exit("organ_like.py: --refine 0..6, --depth 0..0.9 and positive --size; fix: use the defaults")
    v, f = icosphere(a.refine)
    pts = [bean(p, a.depth) for p in v]
    pts = [(x * lx / 2, y * ly / 2, z * lz / 2) for x, y, z in pts]
    if os.path.dirname(a.output):
        os.makedirs(os.path.dirname(a.output), exist_ok=True)
    with open(a.output, "w") as out:
        out.write(f"OFF\n{len(pts)} {len(f)} 0\n")
        for p in pts:
            out.write("%.6f %.6f %.6f\n" % p)
        for t in f:
            out.write("3 %d %d %d\n" % t)
    print(a.output)


if __name__ == "__main__":
    main()
