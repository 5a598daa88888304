#!/usr/bin/env python3
"""Plot an eprop VTKHDF time series: the deformed surface at one step and the time history."""
import argparse
import os
import sys
import tomllib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402
from eprop_series import Fail, open_series  # noqa: E402

EXAMPLES = """examples:
  plot_series.py scenarios/cylinder.h5
  plot_series.py scenarios/cylinder.h5 --out-dir /tmp/plots --step 10
  plot_series.py run.h5 --step -1 --scale 5     # last step, displacement x5

K is the index of an output step (a row of /VTKHDF/Steps/Values), counted from 0;
negative K counts from the last complete step. Only the steps the file's counter
(/eprop/steps_complete) names are read, so a file from an interrupted run can still be
plotted; a file whose header its datasets contradict is refused.
Prints the paths of <stem>_deformed.png and <stem>_history.png, one per line."""


def read(path, step):
    """What the two pictures need from output step `step` of the series at `path` (through
    eprop_series, which checks the file's header before reading it)."""
    if not os.path.isfile(path):
        raise Fail(f"no such file: {path}")
    with open_series(path) as s:
        k = s.step_index(step)
        loads = s.loads()
        xyz, tris = s.surface()
        energy = np.stack([s.field("energy", j) for j in range(s.steps)])
        return dict(
            k=k, n=s.n, points=xyz, tris=tris, time=s.times[k], solver_step=int(s.solver_steps()[k]),
            u=s.field("displacement", k), energy=energy[k], nodes=loads["node"],
            probe_time=loads["time"], probe_u=loads["displacement"],
            volumes=s.control_volumes(), all_energy=energy, tools=tools_at(s, k),
        )


def tools_at(s, k):
    """The scenario's tools where they are at output step k: (shape, radius, normal, position)."""
    if not s.n_tools():
        return []
    defs = tomllib.loads(s.scenario()).get("tool", [])
    pos = s.tools()["position"][k]
    out = []
    for d, c in zip(defs, pos):
        shape = d.get("shape", "sphere")
        out.append((shape, float(d.get("radius", 0.0)), np.asarray(d.get("normal", [0, 0, -1]), float), c))
    return out


def draw_tools(ax, tools):
    """Each tool as a grey wire: a sphere, or a punch's face (a disc, its normal drawn)."""
    for shape, r, normal, c in tools:
        if not r > 0:
            continue
        if shape == "sphere":
            a, b = np.mgrid[0:2 * np.pi:25j, 0:np.pi:13j]
            ax.plot_wireframe(c[0] + r * np.cos(a) * np.sin(b), c[1] + r * np.sin(a) * np.sin(b),
                              c[2] + r * np.cos(b), color="0.35", linewidth=0.5, zorder=20)
        else:
            n = normal / np.linalg.norm(normal)
            e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(n, e1)
            t = np.linspace(0, 2 * np.pi, 49)
            for rr in (r, 0.5 * r):
                ring = c + rr * (np.outer(np.cos(t), e1) + np.outer(np.sin(t), e2))
                ax.plot(ring[:, 0], ring[:, 1], ring[:, 2], color="0.35", lw=0.8, zorder=20)
            back = np.array([c, c - r * n])
            ax.plot(back[:, 0], back[:, 1], back[:, 2], color="0.35", lw=0.8, zorder=20)


def surface_panel(fig, ax, xyz, tris, values, label, d, title):
    coll = Poly3DCollection(xyz[tris], cmap="viridis", edgecolor="k", linewidth=0.1)
    coll.set_array(values[tris].mean(axis=1))
    ax.add_collection3d(coll)
    if len(d["nodes"]):
        c = xyz[d["nodes"]]
        ax.scatter(c[:, 0], c[:, 1], c[:, 2], color="red", s=40, depthshade=False,
                   zorder=10, label="contact node")
        ax.legend(loc="upper left", fontsize=8)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    mid, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set(xlim=(mid[0] - half, mid[0] + half), ylim=(mid[1] - half, mid[1] + half),
           zlim=(mid[2] - half, mid[2] + half), xlabel="x", ylabel="y", zlabel="z", title=title)
    ax.set_box_aspect((1, 1, 1))
    ax.locator_params(nbins=5)
    ax.tick_params(labelsize=8)
    fig.colorbar(coll, ax=ax, shrink=0.6, label=label)


def plot_deformed(d, scale, out, stem):
    xyz = d["points"] + scale * d["u"]
    fig = plt.figure(figsize=(13, 6.5))
    when = f"t = {d['time']:.4g} (output step {d['k']}, solver step {d['solver_step']})"
    sfx = f", displacement x{scale:g}" if scale != 1 else ""
    panels = [(d["energy"], "energy |phi|", "energy |phi|"),
              (np.linalg.norm(d["u"], axis=1), "|displacement|", "|displacement|")]
    for i, (vals, label, name) in enumerate(panels):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d", computed_zorder=False)
        # turn the loaded side (or the first tool) towards the viewer
        focus = d["points"][d["nodes"][0]] if len(d["nodes"]) else (d["tools"][0][3] if d["tools"] else None)
        if focus is not None:
            r = focus - d["points"].mean(axis=0)
            ax.view_init(elev=15, azim=np.degrees(np.arctan2(r[1], r[0])) - 25)
        surface_panel(fig, ax, xyz, d["tris"], vals, label, d, f"{name}\n{when}{sfx}")
        draw_tools(ax, d["tools"])
    path = os.path.join(out, stem + "_deformed.png")
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_history(d, out, stem):
    t = d["probe_time"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for l, node in enumerate(d["nodes"]):
        a1.plot(t, np.linalg.norm(d["probe_u"][:, l], axis=1), label=f"load {l} (node {node})")
    if len(d["nodes"]):
        a1.legend()
    else:
        a1.text(0.5, 0.5, "no loads", transform=a1.transAxes, ha="center")
    a1.set(ylabel="|displacement| at contact node", title="Contact node displacement")
    a2.plot(t, d["all_energy"] @ d["volumes"], color="tab:orange")
    a2.set(xlabel="time", ylabel="sum V_i * energy_i", title="Total energy")
    for a in (a1, a2):
        a.axvline(d["time"], color="gray", ls="--", lw=0.8)
        a.grid(alpha=0.3)
    path = os.path.join(out, stem + "_history.png")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main():
    p = argparse.ArgumentParser(
        description="Plot an eprop result file (VTKHDF time series): the deformed boundary "
                    "surface at one step, coloured by energy |phi| and by |displacement|, "
                    "and the history of contact-node displacement and total energy.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", metavar="FILE.h5", help="HDF5 file written by `eprop run`")
    p.add_argument("--out-dir", metavar="DIR", help="where to write the PNGs (default: beside FILE.h5)")
    p.add_argument("--step", metavar="K", type=int, default=-1,
                   help="output step to draw (default: the last complete step)")
    p.add_argument("--scale", metavar="S", type=float, default=1.0,
                   help="displacement magnification for the deformed surface (default: 1)")
    a = p.parse_args()
    try:
        d = read(a.file, a.step)
        out = a.out_dir or os.path.dirname(os.path.abspath(a.file))
        os.makedirs(out, exist_ok=True)
        stem = os.path.splitext(os.path.basename(a.file))[0]
        print(plot_deformed(d, a.scale, out, stem))
        print(plot_history(d, out, stem))
    except (Fail, OSError, KeyError, ValueError, IndexError) as e:
        print(f"plot_series.py: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
