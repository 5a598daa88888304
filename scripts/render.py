#!/usr/bin/env python3
"""Render the deformed mesh of an eprop run coloured by a field (the paper's figures 3, 4, 6, 7).

Uses VTK off-screen (vtkUnstructuredGrid -> surface -> PNG, with a scalar bar and the time).

The camera: --view iso (the default: from +x, a little from -y and above, z up), auto (facing
the dent: from the side of the point that moved most), +x, -x, +y, -y, +z or -z (looking at
the mesh from that side); or --azimuth A --elevation E in degrees (A from +x towards +y in the
x-y plane, E above it), which override --view. With tools, auto looks at the first tool's
contact (from the side the tool comes from).

The tools of the run ([[tool]]: spheres and punches) are drawn where they are at the step, in
translucent grey (--no-tools leaves them out).

examples:
  render.py run.h5 -o frame.png                    # last complete step, coloured by energy
  render.py run.h5 -o frame.png --step 10 --scale 3 --field energy
  render.py tongue.h5 -o dent.png --view auto      # look at the dent
  render.py run.h5 -o top.png --azimuth 0 --elevation 80
Prints the path of the PNG."""

VIEWS = {"iso": (1.6, -1.0, 0.6), "+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
         "+z": (0, 0, 1), "-z": (0, 0, -1)}


def camera_direction(a, s, k):
    """Unit vector from the mesh's centre towards the camera."""
    if a.azimuth is not None or a.elevation is not None:
        az, el = np.radians(a.azimuth or 0.0), np.radians(a.elevation or 0.0)
        return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    if a.view == "auto":
        tools = tool_solids(s, k)
        if tools:
            shape, p, r, n = tools[0]
            lo, hi = s.points.min(axis=0), s.points.max(axis=0)
            d = -n if shape == "punch" else p - (lo + hi) / 2
            if np.linalg.norm(d) > 1e-12 * float(np.linalg.norm(hi - lo)):
                # from the tool's side but turned about 55 degrees, so that the dent shows in
                # profile beside the tool instead of hidden behind it
                d = d / np.linalg.norm(d)
                side = np.cross([0.0, 0.0, 1.0], d)
                side = side / np.linalg.norm(side) if np.linalg.norm(side) > 0.3 else np.array([0.0, -1.0, 0.0])
                return 0.55 * d + 0.8 * side + np.array([0.0, 0.0, 0.25])
        p = s.focus(k)
        if p is not None:
            lo, hi = s.points.min(axis=0), s.points.max(axis=0)
            r = p - (lo + hi) / 2
            if np.linalg.norm(r) > 1e-12 * float(np.linalg.norm(hi - lo)):
                # a little from above, so that the surface around the dent shows
                d = r / np.linalg.norm(r)
                return d + np.array([0.0, 0.0, 0.3]) if abs(d[2]) < 0.9 else d + np.array([0.3, -0.2, 0.0])
        print("render.py: nothing moved; --view auto falls back to iso", file=sys.stderr)
        return np.array(VIEWS["iso"], dtype=float)
    return np.array(VIEWS[a.view], dtype=float)


def tool_solids(s, k):
    """The tools at output step k: (shape, position, radius, unit normal) from the scenario's
    [[tool]] tables and /eprop/tools/position; [] without tools."""
    if s.n_tools() == 0:
        return []
    try:
        import tomllib
        tables = tomllib.loads(s.scenario()).get("tool", [])
    except Exception:
        return []
    pos = s.tools()["position"][k]
    out = []
    for j, t in enumerate(tables[: pos.shape[0]]):
        n = np.asarray(t.get("normal", [0.0, 0.0, -1.0]), dtype=float)
        n = n / np.linalg.norm(n) if np.linalg.norm(n) > 0 else np.array([0.0, 0.0, -1.0])
        shape = str(t.get("shape", "sphere"))
        r = float(t.get("radius", 0.0))
        if r > 0 and np.isfinite(pos[j]).all():
            out.append((shape, np.asarray(pos[j], dtype=float), r, n))
    return out


def tool_actor(vtk, shape, p, r, n, scale_len):
    """A translucent grey solid: the sphere, or the punch's disc face with a short body behind it
    (the punch is the half-infinite cylinder behind its face, drawn 1.5 R long)."""
    if shape == "punch":
        h = 1.5 * r
        src = vtk.vtkCylinderSource()
        src.SetRadius(r)
        src.SetHeight(h)
        src.SetResolution(48)
        # the cylinder source's axis is y; turn it onto n and put its centre behind the face
        y = np.array([0.0, 1.0, 0.0])
        axis = np.cross(y, n)
        angle = np.degrees(np.arctan2(np.linalg.norm(axis), float(np.dot(y, n))))
        tf = vtk.vtkTransform()
        tf.Translate(*(p - 0.5 * h * n))
        if np.linalg.norm(axis) > 1e-12:
            tf.RotateWXYZ(angle, *axis)
        elif np.dot(y, n) < 0:
            tf.RotateWXYZ(180.0, 1.0, 0.0, 0.0)
        f = vtk.vtkTransformPolyDataFilter()
        f.SetTransform(tf)
        f.SetInputConnection(src.GetOutputPort())
        port = f.GetOutputPort()
    else:
        src = vtk.vtkSphereSource()
        src.SetCenter(*p)
        src.SetRadius(r)
        src.SetThetaResolution(48)
        src.SetPhiResolution(24)
        port = src.GetOutputPort()
    m = vtk.vtkPolyDataMapper()
    m.SetInputConnection(port)
    m.ScalarVisibilityOff()
    act = vtk.vtkActor()
    act.SetMapper(m)
    act.GetProperty().SetColor(0.55, 0.55, 0.6)
    act.GetProperty().SetOpacity(0.45)
    return act


import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
from argv_glue import glued  # noqa: E402
from eprop_series import Fail, open_series  # noqa: E402




def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", help="eprop series (.h5)")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    ap.add_argument("--step", type=int, default=-1, help="output step, negative from the last (default -1)")
    ap.add_argument("--scale", type=float, default=1.0, help="displacement magnification (default 1)")
    ap.add_argument("--field", default="energy", help="point field to colour by (default energy)")
    ap.add_argument("--size", default="900x700", help="image size WxH (default 900x700)")
    ap.add_argument("--view", default="iso", choices=["auto", *VIEWS],
                    help="camera: iso (default), auto (facing the dent) or a side")
    ap.add_argument("--azimuth", type=float, help="camera azimuth in degrees (from +x towards +y)")
    ap.add_argument("--elevation", type=float, help="camera elevation in degrees (above the x-y plane)")
    ap.add_argument("--no-tools", action="store_true", help="do not draw the run's tools")
    a = ap.parse_args(glued(sys.argv[1:], {"--view", "--azimuth", "--elevation", "--step"}))
    try:
        import vtk
        from vtk.util import numpy_support as ns
    except ImportError:
        raise Fail("the vtk module is missing; fix: scripts/setup.sh installs it into .venv (pip install vtk)")
    s = open_series(a.file)
    k = s.step_index(a.step)
    u = s.field("displacement", k)
    val = s.field(a.field, k)
    if val.ndim == 2:
        val = np.linalg.norm(val, axis=1)
    conn, offs, types = s.cells()
    pts = s.points + a.scale * u
    grid = vtk.vtkUnstructuredGrid()
    vp = vtk.vtkPoints()
    vp.SetData(ns.numpy_to_vtk(np.ascontiguousarray(pts), deep=True))
    grid.SetPoints(vp)
    ca = vtk.vtkCellArray()
    ca.SetData(ns.numpy_to_vtkIdTypeArray(np.ascontiguousarray(offs, dtype=np.int64), deep=True),
               ns.numpy_to_vtkIdTypeArray(np.ascontiguousarray(conn, dtype=np.int64), deep=True))
    grid.SetCells(ns.numpy_to_vtk(np.ascontiguousarray(types, dtype=np.uint8), deep=True,
                                  array_type=vtk.VTK_UNSIGNED_CHAR), ca)
    arr = ns.numpy_to_vtk(np.ascontiguousarray(val), deep=True)
    arr.SetName(a.field)
    grid.GetPointData().SetScalars(arr)
    surf = vtk.vtkDataSetSurfaceFilter()
    surf.SetInputData(grid)
    mapper = vtk.vtkPolyDataMapper()
    mapper.SetInputConnection(surf.GetOutputPort())
    lo, hi = float(val.min()), float(val.max())
    mapper.SetScalarRange(lo, hi if hi > lo else lo + 1.0)
    lut = vtk.vtkLookupTable()
    lut.SetHueRange(0.667, 0.0)
    lut.Build()
    mapper.SetLookupTable(lut)
    actor = vtk.vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().EdgeVisibilityOn()
    actor.GetProperty().SetEdgeColor(0.2, 0.2, 0.2)
    bar = vtk.vtkScalarBarActor()
    bar.SetLookupTable(lut)
    bar.SetTitle(a.field)
    for tp in (bar.GetTitleTextProperty(), bar.GetLabelTextProperty()):
        tp.SetColor(0, 0, 0)
        tp.ItalicOff()
        tp.ShadowOff()
    text = vtk.vtkTextActor()
    text.SetInput(f"{os.path.basename(a.file)}  step {k}  t = {s.times[k]:.4g}  (u x {a.scale:g})")
    text.GetTextProperty().SetFontSize(18)
    text.GetTextProperty().SetColor(0, 0, 0)
    ren = vtk.vtkRenderer()
    ren.SetBackground(1, 1, 1)
    ren.AddActor(actor)
    if not a.no_tools:
        for shape, p, r, n in tool_solids(s, k):
            ren.AddActor(tool_actor(vtk, shape, p, r, n, 1.0))
    ren.AddViewProp(bar)
    ren.AddViewProp(text)
    lo3, hi3 = pts.min(axis=0), pts.max(axis=0)
    c = (lo3 + hi3) / 2
    d = float(np.linalg.norm(hi3 - lo3))
    look = camera_direction(a, s, k)
    look = look / np.linalg.norm(look)
    cam = ren.GetActiveCamera()
    cam.SetFocalPoint(*c)
    cam.SetPosition(*(c + 2.0 * d * look))
    # z up, unless the camera looks along z
    cam.SetViewUp(*((0, 1, 0) if abs(look[2]) > 0.95 else (0, 0, 1)))
    ren.ResetCamera()
    try:
        w, h = (int(x) for x in a.size.split("x"))
    except ValueError:
        raise Fail(f"--size {a.size}: give the image size as WxH, e.g. 900x700")
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetSize(w, h)
    win.AddRenderer(ren)
    win.Render()
    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(win)
    grab.Update()
    png = vtk.vtkPNGWriter()
    png.SetFileName(a.output)
    png.SetInputConnection(grab.GetOutputPort())
    png.Write()
    s.close()
    if not os.path.exists(a.output):
        raise Fail(f"{a.output}: VTK wrote no image (no off-screen OpenGL: install libegl1 libegl-mesa0 libgl1-mesa-dri)")
    print(a.output)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"render.py: {e}")
