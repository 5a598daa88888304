#!/usr/bin/env python3
"""Tests of eprop_series.py and the scripts that use it, on three runs of the same mesh: one with
a [[load]], one with a [[tool]] only, one with neither. No pytest: every check is an assert,
the script prints one line per test and exits non-zero on the first failure.

examples:
  test_postprocess.py --load load.h5 --tool tool.h5 --bare bare.h5 --tmp /tmp/pp
(tests/postprocess.rs makes the runs and calls it; so does `cargo test --test postprocess`.)"""
import argparse
import contextlib
import io
import os
import subprocess
import sys

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, here)
import numpy as np  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.figure  # noqa: E402
import matplotlib.image  # noqa: E402
import eprop_series as es  # noqa: E402


def script(name, *args):
    """(returncode, stdout, stderr) of scripts/NAME run with this Python."""
    p = subprocess.run([sys.executable, os.path.join(here, name), *args], capture_output=True, text=True,
                       env={**os.environ, "MPLBACKEND": "Agg"})
    assert "Traceback" not in p.stderr, f"{name} {args}: {p.stderr}"
    return p.returncode, p.stdout, p.stderr


def not_blank(png):
    assert os.path.getsize(png) > 0, png
    a = matplotlib.image.imread(png)
    assert float(a[..., :3].std()) > 0.01, f"{png} is blank"


def figures_of(module, argv):
    """The figures `module.main()` saves, in process (their lines can be inspected)."""
    saved = []
    real = matplotlib.figure.Figure.savefig

    def keep(fig, *a, **k):
        saved.append(fig)
        return real(fig, *a, **k)

    matplotlib.figure.Figure.savefig = keep
    old = sys.argv
    sys.argv = [module.__name__ + ".py", *argv]
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            module.main()
    finally:
        sys.argv = old
        matplotlib.figure.Figure.savefig = real
    return saved


def labels(fig):
    return [ln.get_label() for ax in fig.axes for ln in ax.get_lines()]


def test_module(load, tool, bare):
    for path, nl, nt in [(load, 1, 0), (tool, 0, 1), (bare, 0, 0)]:
        with es.open_series(path) as s:
            assert s.steps >= 2 and s.times.shape == (s.steps,), path
            assert (s.n_loads(), s.n_tools()) == (nl, nt), (path, s.n_loads(), s.n_tools())
            ld = s.loads()
            assert ld["node"].shape == (nl,)
            assert ld["force"].shape == ld["displacement"].shape == (s.steps, nl, 3), ld["force"].shape
            # the file's own datasets have the same shape (no phantom probe)
            assert s.f["eprop/probes/displacement"].shape == (s.steps, nl, 3)
            assert np.array_equal(s.solver_steps(), ld["step"]) and np.all(np.diff(ld["step"]) > 0)
            if nt:
                t = s.tools()
                assert t["force"].shape == (s.steps, nt, 3) and t["indentation"].shape == (s.steps, nt)
            else:
                try:
                    s.tools()
                    raise AssertionError(f"{path}: tools() of a run without tools")
                except es.Fail as e:
                    assert "no [[tool]]" in str(e)
            assert set(s.fields()) >= {"displacement", "energy"}
            u = s.field("displacement", -1)
            assert u.shape == (s.n, 3) and np.array_equal(u, s.field("displacement", s.steps - 1))
            try:
                s.field("displacement", s.steps)
                raise AssertionError("a step past the last")
            except es.Fail as e:
                assert "not in the file" in str(e)
            # the outer surface: closed (every edge in exactly two triangles), and moved by u
            xyz, tris = s.surface(-1, scale=2.0)
            assert tris.ndim == 2 and tris.shape[1] == 3 and len(tris) > 0
            assert tris.min() >= 0 and tris.max() < s.n
            e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
            _, count = np.unique(e, axis=0, return_counts=True)
            assert np.all(count == 2), "the surface is not closed"
            assert np.array_equal(xyz, s.points + 2.0 * u)
            rest, _ = s.surface()
            assert np.array_equal(rest, s.points)
            text = s.describe()
            assert ("loads   none" in text) == (nl == 0) and ("tools   none" in text) == (nt == 0), text
            if nl:
                assert np.linalg.norm(ld["displacement"][-1, 0]) > 0
            f = s.focus(-1)
            assert (f is None) == (nl == 0 and nt == 0), (path, f)
    # the dent of the load run is where its load presses
    with es.open_series(load) as s:
        node = s.loads()["node"][0]
        assert np.linalg.norm(s.focus(-1) - s.points[node]) < 0.5, (s.focus(-1), s.points[node])
    for bad, msg in [("/nonexistent.h5", "no such file")]:
        try:
            es.open_series(bad)
            raise AssertionError(bad)
        except es.Fail as e:
            assert msg in str(e), e
    rc, out, _ = script("eprop_series.py", load, tool, bare)
    assert rc == 0 and out.count("complete output steps") == 3 and "tool 0" in out, out


def test_force_displacement(load, tool, bare, tmp):
    import force_displacement as fd
    png = os.path.join(tmp, "fd_load.png")
    rc, out, err = script("force_displacement.py", load, "-o", png)
    assert rc == 0 and png in out, err
    not_blank(png)
    # a tool-only run: the tool's force and displacement, not an empty plot
    png = os.path.join(tmp, "fd_tool.png")
    (fig,) = figures_of(fd, [tool, "-o", png])
    (line,) = fig.axes[0].get_lines()
    assert "tool 0" in line.get_label() and np.ptp(line.get_xdata()) > 0 and np.ptp(line.get_ydata()) > 0
    not_blank(png)
    rc, _, err = script("force_displacement.py", tool, "--load", "0", "-o", png)
    assert rc != 0 and "no load 0" in err and "--tool" in err, err
    # neither: a message and a non-zero status, no picture
    png = os.path.join(tmp, "fd_bare.png")
    rc, out, err = script("force_displacement.py", bare, "-o", png)
    assert rc != 0 and "no [[load]] and no [[tool]]" in err and not os.path.exists(png), (rc, err)


def test_history(load, tool, bare, tmp):
    import history
    for path, want, unwanted in [(load, ["load 0"], ["tool"]), (tool, ["tool 0"], ["load"]),
                                 (bare, [], ["load", "tool"])]:
        png = os.path.join(tmp, "history.png")
        (fig,) = figures_of(history, [path, "-o", png])
        names = labels(fig)
        assert "max |u|" in names, names
        for w in want:
            assert any(w in n for n in names), (path, names)
        for w in unwanted:
            assert not any(w in n for n in names), (path, names)
        not_blank(png)


def test_render(load, tool, bare, tmp):
    import render
    a = argparse.Namespace(view="auto", azimuth=None, elevation=None)
    with es.open_series(tool) as s:
        # the demo's sphere presses the cylinder's +x side: auto looks from that side, turned
        # about 55 degrees so that the dent shows in profile beside the tool
        d = render.camera_direction(a, s, -1)
        h = d[:2] / np.linalg.norm(d[:2])
        assert h[0] > 0.4 and abs(h[1]) > 0.6, d
        assert len(render.tool_solids(s, -1)) == 1, "the demo's sphere is drawn"
        a.view = "-y"
        assert np.array_equal(render.camera_direction(a, s, -1), [0, -1, 0])
        a.azimuth, a.elevation = 90.0, 0.0
        assert np.allclose(render.camera_direction(a, s, -1), [0, 1, 0])
    try:
        import vtk  # noqa: F401
    except ImportError:
        print("test_render: vtk missing, the pictures are not drawn")
        return
    for path, extra in [(tool, ["--view", "auto"]), (load, ["--azimuth", "30", "--elevation", "20"]),
                        (bare, ["--view", "auto"])]:
        png = os.path.join(tmp, "render.png")
        rc, out, err = script("render.py", path, "-o", png, "--scale", "3", *extra)
        assert rc == 0 and png in out, err
        not_blank(png)
    rc, _, err = script("render.py", tool, "-o", png, "--view", "sideways")
    assert rc == 2 and "invalid choice" in err, err


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--load", required=True, help="series of a run with one [[load]]")
    ap.add_argument("--tool", required=True, help="series of a run with one [[tool]] and no load")
    ap.add_argument("--bare", required=True, help="series of a run with neither")
    ap.add_argument("--tmp", required=True, help="a directory for the pictures")
    a = ap.parse_args()
    os.makedirs(a.tmp, exist_ok=True)
    test_module(a.load, a.tool, a.bare)
    print("test_module: ok")
    for t in (test_force_displacement, test_history, test_render):
        t(a.load, a.tool, a.bare, a.tmp)
        print(f"{t.__name__}: ok")


if __name__ == "__main__":
    main()
