#!/usr/bin/env python3
"""A client of `eprop serve` (docs/protocol.md): drives a live tool (or load) and plots the
force it gets back.

It moves tool K in a straight line from --from to --to over --duration seconds of simulated
time (and back again with --back), sending a pose every 1/--rate seconds of wall-clock time
(simulated time = wall-clock time x --speed), or sends the rows of a table (--path, columns
t, x, y, z) at their times. Every message gets an answer at once: the contact force and
displacement of the latest physics step, extrapolated to the message's time. At the end it
says bye, prints the round-trip times and how many answers were extrapolated beyond the latest
physics step, writes the PNG (force against time and against the tool's travel) and prints its
path.

It speaks protocol version 3: while the physics lags, the server extrapolates its answers up to
10 steps ahead and flags them (bit 0: extrapolated more than one step; bit 1: the lag passes 10
steps, so the answer is still behind the message's time); the flags go to the CSV. With
--stream K it also asks for the deformed surface: the server sends
the outer surface once (rest coordinates, node ids, triangles), then after its answers the
displacements of the surface nodes of every K-th step it reaches (f32, or f64 with --f64). The
client prints the sizes, the frames and bytes received, and with --obj writes the last frame's
deformed surface as OBJ (a viewer's input).

The scenario served needs a `live = true` tool or load (scenarios/cylinder_live.toml has a live
sphere); for real time, match its dt to the haptic loop (docs/protocol.md, "Real-time settings").

examples:
  eprop serve scenarios/cylinder_live.toml --listen 127.0.0.1:5555 &
  haptic_client.py 127.0.0.1:5555 --from 1.85,0,2 --to 1.5,0,2 --duration 40 --back --speed 40 -o force.png
  haptic_client.py 127.0.0.1:5555 --path scenarios/cylinder_indent_path.csv -o force.png --csv answers.csv
  # the deformed surface too, a frame every 10 steps; the last one written as OBJ:
  haptic_client.py 127.0.0.1:5555 --path scenarios/cylinder_indent_path.csv -o force.png --stream 10 --obj last.obj
  # a scenario with a live load (a [[load]] with live = true) instead of a tool:
  haptic_client.py 127.0.0.1:5555 --load 0 --from 0,0,0 --to 0,0,-0.3 --duration 10 -o f.png
"""
import argparse
import csv
import socket
import struct
import sys
import time

from argv_glue import glued

MAGIC = b"EPROPHAP"
VERSION = 3  # version 2's hello and stream, answers flagged while the physics lags
STREAM_SURFACE = 1
POSE, FORCE, BYE = 2, 3, 4
HELLO, A_TOOL, A_LOAD, A_BYE, A_END, TOPOLOGY, FRAME, A_ERROR = 1, 2, 3, 4, 5, 6, 7, 255
CLIENT = struct.Struct("<IIdddd")  # kind, index, t, x, y, z: 40 bytes
ANSWER = struct.Struct("<IHHQdddddddd")  # kind, index, flags, step, t_step, t, force[3], displacement[3]: 80 bytes
EXTRAPOLATED, BEYOND_REACH = 1, 2  # answer flags (version 3)
HELLO_REPLY = struct.Struct("<II8sIIIIdddQII8x")


class Fail(Exception):
    pass


def recv_exact(s, n):
    b = b""
    while len(b) < n:
        chunk = s.recv(n - len(b))
        if not chunk:
            raise Fail("the server closed the connection")
        b += chunk
    return b


class Surface:
    """The surface stream (protocol versions 2 and 3): the topology and the latest frame."""

    def __init__(self):
        self.n = self.m = 0
        self.rest, self.ids, self.tris = [], [], []
        self.frames, self.bytes = 0, 0
        self.first_step = self.step = None
        self.u = None

    def take(self, kind, head, payload):
        width, size, n = struct.unpack_from("<IQI", head, 4)
        f = "f" if width == 4 else "d"
        self.bytes += 80 + size
        if kind == TOPOLOGY:
            self.n, self.m = n, struct.unpack_from("<I", head, 20)[0]
            self.rest = struct.unpack_from(f"<{3 * n}{f}", payload, 0)
            self.ids = struct.unpack_from(f"<{n}I", payload, 3 * n * width)
            self.tris = struct.unpack_from(f"<{3 * self.m}I", payload, 3 * n * width + 4 * n)
        else:
            self.step = struct.unpack_from("<Q", head, 32)[0]
            if self.first_step is None:
                self.first_step = self.step
            self.u = struct.unpack(f"<{3 * n}{f}", payload)
            self.frames += 1

    def write_obj(self, path):
        with open(path, "w") as f:
            f.write(f"# eprop serve: deformed surface at step {self.step}\n")
            for i in range(self.n):
                x = [self.rest[3 * i + d] + self.u[3 * i + d] for d in range(3)]
                f.write(f"v {x[0]!r} {x[1]!r} {x[2]!r}\n")
            for k in range(self.m):
                a, b, c = self.tris[3 * k:3 * k + 3]
                f.write(f"f {a + 1} {b + 1} {c + 1}\n")


def read_reply(s, surface=None):
    """The next message that is not a topology or frame (those go to `surface`)."""
    while True:
        b = recv_exact(s, 80)
        kind = struct.unpack_from("<I", b)[0]
        if kind == A_ERROR:
            code = struct.unpack_from("<I", b, 4)[0]
            text = b[8:].split(b"\0", 1)[0].decode("utf-8", "replace")
            raise Fail(f"server error {code}: {text}")
        if kind in (TOPOLOGY, FRAME):
            payload = recv_exact(s, struct.unpack_from("<Q", b, 8)[0])
            if surface is None:
                raise Fail(f"a stream message (kind {kind}) the client did not ask for")
            surface.take(kind, b, payload)
            continue
        return kind, b


def hello(s, stream=0, width=4, surface=None):
    if stream:
        s.sendall(MAGIC + struct.pack("<IIII", VERSION, STREAM_SURFACE, stream, width) + bytes(16))
    else:
        s.sendall(MAGIC + struct.pack("<I", VERSION) + bytes(28))
    kind, b = read_reply(s, surface)
    if kind != HELLO:
        raise Fail(f"expected the server's hello, got message kind {kind}")
    (_, version, magic, tools, loads, live_tools, live_loads, dt, t0, timeout, max_steps, n, m) = HELLO_REPLY.unpack(b)
    if magic != MAGIC:
        raise Fail("the server is not eprop serve")
    if version != VERSION:
        raise Fail(f"the server answered version {version}; this client speaks version {VERSION}")
    return dict(tools=tools, loads=loads, live_tools=live_tools, live_loads=live_loads, dt=dt, t0=t0,
                timeout=timeout, max_steps=max_steps, surface_nodes=n, surface_triangles=m)


def vec(text):
    v = [float(x) for x in text.split(",")]
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"{text}: give x,y,z")
    return v


def read_path(path):
    rows = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = [p.strip() for p in line.split(",")]
            try:
                rows.append([float(p) for p in parts])
            except ValueError:
                if rows:
                    raise Fail(f"{path}: `{line}` is not a row of numbers")
    if not rows or any(len(r) != 4 for r in rows):
        raise Fail(f"{path}: expected rows of t, x, y, z")
    return rows


def samples(a, t0):
    """(simulated time, values) to send, in order, and the wall-clock time to send each."""
    if a.path:
        for r in read_path(a.path):
            yield r[0], r[1:], (r[0] - t0) / a.speed if a.speed > 0 else 0.0
        return
    legs = [(a.from_, a.to)] + ([(a.to, a.from_)] if a.back else [])
    n = max(1, int(round(a.duration / a.speed * a.rate)))
    k = 0
    for (p, q) in legs:
        for i in range(n + 1):
            if k > 0 and i == 0:
                continue
            s = i / n
            t = t0 + k * a.duration / n
            yield t, [p[d] + s * (q[d] - p[d]) for d in range(3)], k / a.rate
            k += 1




def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("address", help="HOST:PORT that eprop serve listens on")
    ap.add_argument("--tool", type=int, help="tool index (default: the first live tool)")
    ap.add_argument("--load", type=int, help="drive load K instead of a tool (values are forces)")
    ap.add_argument("--from", dest="from_", type=vec, help="start position (or force) x,y,z")
    ap.add_argument("--to", type=vec, help="end position (or force) x,y,z")
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds from --from to --to")
    ap.add_argument("--back", action="store_true", help="return to --from afterwards")
    ap.add_argument("--path", help="send the rows of this table (t, x, y, z) instead")
    ap.add_argument("--rate", type=float, default=1000.0, help="messages per wall-clock second (default 1000)")
    ap.add_argument("--speed", type=float, default=1.0,
                    help="simulated seconds per wall-clock second (0 with --path: as fast as possible)")
    ap.add_argument("--connect-timeout", type=float, default=30.0, help="seconds to wait for the server")
    ap.add_argument("-o", "--output", required=True, help="PNG to write")
    ap.add_argument("--csv", help="also write every answer to this CSV file")
    ap.add_argument("--stream", type=int, default=0, metavar="K",
                    help="ask for the deformed surface (the stream of protocol version 2), a frame of every K-th step")
    ap.add_argument("--f64", action="store_true", help="stream f64 values (default f32)")
    ap.add_argument("--obj", help="write the last frame's deformed surface to this OBJ file (needs --stream)")
    a = ap.parse_args(glued(sys.argv[1:], {"--from", "--to"}))
    if a.stream < 0 or (a.obj and not a.stream):
        ap.error("--stream takes K >= 1; --obj needs --stream")
    if not a.path and (a.from_ is None or a.to is None):
        ap.error("give --from and --to, or --path")
    if a.rate <= 0 or (a.speed <= 0 and not a.path):
        ap.error("--rate and --speed must be positive")
    host, _, port = a.address.rpartition(":")
    deadline = time.monotonic() + a.connect_timeout
    while True:
        try:
            s = socket.create_connection((host, int(port)), timeout=a.connect_timeout)
            break
        except OSError as e:
            if time.monotonic() > deadline:
                raise Fail(f"{a.address}: cannot connect: {e}")
            time.sleep(0.1)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    surface = Surface() if a.stream else None
    h = hello(s, a.stream, 8 if a.f64 else 4, surface)
    if a.load is not None:
        kind, index, mask, what = FORCE, a.load, h["live_loads"], "load"
    else:
        kind, mask, what = POSE, h["live_tools"], "tool"
        index = a.tool if a.tool is not None else next((k for k in range(32) if mask >> k & 1), None)
        if index is None:
            raise Fail("the scenario has no live tool; give --load K to drive a load")
    if not mask >> index & 1:
        raise Fail(f"{what} {index} is not live in the server's scenario")
    rows, rtts = [], []
    start = time.perf_counter()
    first = None
    for t, v, at in samples(a, h["t0"]):
        wait = start + at - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        sent = time.perf_counter()
        s.sendall(CLIENT.pack(kind, index, t, *v))
        k, b = read_reply(s, surface)
        rtts.append(time.perf_counter() - sent)
        if k == A_END:
            print("the run reached its end", file=sys.stderr)
            break
        _, _, flags, step, t_step, t_ans, fx, fy, fz, ux, uy, uz = ANSWER.unpack(b)
        first = first or v
        travel = sum((v[d] - first[d]) ** 2 for d in range(3)) ** 0.5
        rows.append((t, v, step, t_step, t_ans, (fx, fy, fz), (ux, uy, uz), travel, flags))
    else:
        s.sendall(CLIENT.pack(BYE, 0, 0.0, 0.0, 0.0, 0.0))
        try:
            read_reply(s, surface)
        except Fail:
            pass
    s.close()
    if not rows:
        raise Fail("no answer received")
    wall = time.perf_counter() - start
    r = sorted(rtts)
    p = lambda q: r[min(len(r) - 1, int(q * len(r)))] * 1e3  # noqa: E731
    print(f"{len(rows)} answers in {wall:.2f} s ({len(rows) / wall:.0f}/s); round trip p50 {p(0.5):.3f} ms, "
          f"p99 {p(0.99):.3f} ms, max {r[-1] * 1e3:.3f} ms; physics steps {rows[0][2]}..{rows[-1][2]}",
          file=sys.stderr)
    extrapolated = sum(1 for row in rows if row[8] & EXTRAPOLATED)
    beyond = sum(1 for row in rows if row[8] & BEYOND_REACH)
    print(f"{extrapolated} of {len(rows)} answers extrapolated beyond the latest physics step "
          f"({beyond} of them still behind the message's time: the physics lagged more than 10 steps)",
          file=sys.stderr)
    if surface is not None:
        print(f"surface: {surface.n} nodes, {surface.m} triangles; {surface.frames} frames "
              f"(steps {surface.first_step}..{surface.step}), {surface.bytes / 1e6:.2f} MB streamed", file=sys.stderr)
        if a.obj:
            if surface.u is None:
                raise Fail("no frame arrived, so there is no deformed surface to write")
            surface.write_obj(a.obj)
            print(a.obj)
    if a.csv:
        with open(a.csv, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t", "x", "y", "z", "step", "t_step", "t_answer", "fx", "fy", "fz", "ux", "uy", "uz", "rtt_ms",
                        "flags"])
            for (t, v, step, ts, ta, fo, u, _, fl), rt in zip(rows, rtts):
                w.writerow([t, *v, step, ts, ta, *fo, *u, rt * 1e3, fl])
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fmag = [sum(c * c for c in row[5]) ** 0.5 for row in rows]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    a1.plot([row[4] for row in rows], fmag)
    a1.set_xlabel("time of the answer")
    a1.set_ylabel(f"|force| on the {what}")
    a1.grid(alpha=0.3)
    a2.plot([row[7] for row in rows], fmag)
    a2.set_xlabel("travel since the first sample" if kind == POSE else "|force sent - first force sent|")
    a2.set_ylabel("|force|")
    a2.grid(alpha=0.3)
    fig.suptitle(f"eprop serve {a.address}: {len(rows)} answers, round trip p99 {p(0.99):.2f} ms")
    fig.tight_layout()
    fig.savefig(a.output, dpi=110)
    print(a.output)


if __name__ == "__main__":
    try:
        main()
    except Fail as e:
        sys.exit(f"haptic_client.py: {e}")
    except (ConnectionError, socket.timeout) as e:
        sys.exit(f"haptic_client.py: the connection failed: {e}")
