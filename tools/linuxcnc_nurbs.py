#!/usr/bin/env python3
"""linuxcnc_nurbs.py - LinuxCNC 2.9's own segmentation of G5/G5.1/G5.2 curves, read out
of its binaries with gdb.

Python 3 standard library, gdb (with its Python support) and the Debian package
linuxcnc-uspace (tested with 2.9.0~pre1+git20230208.f1270d6ed7-1+deb12u2 on Debian
bookworm, x86-64).

WHY
    The interpreter turns G5, G5.1 and G5.2 ... G5.3 into one canonical call,
    NURBS_FEED(control points, order).  The standalone interpreter rs274 prints it as
    "NURBS_FEED(n, ...)" without the points, and the curve becomes motion only in the
    task (milltask, emccanon.cc NURBS_FEED): it evaluates the curve at 4 x (number of
    control points) equal steps of the knot parameter and joins each pair of points
    with a biarc (two ARC_FEED calls, or STRAIGHT_FEED where an arc degenerates).  This
    script gets both halves from the installed binaries themselves:

      points    runs rs274 under gdb and records the control points (X, Y, weight;
                program units and coordinates) and the order of every NURBS_FEED call;
      segments  calls milltask's own NURBS_FEED under gdb for each curve, with
                ARC_FEED and STRAIGHT_FEED patched to return at once, and records their
                arguments: the end point (and for an arc the centre and the rotation,
                +1 counter-clockwise, -1 clockwise) of every piece, in the program
                units and coordinates of the control points.  The other arguments
                (the plane-normal coordinate, A, B, C) are the position the machine
                is at, taken by the caller.

    A piece whose end point is not finite (LinuxCNC's biarc between two parallel
    tangents, on a straight part of a curve, divides by zero) is printed with "null"
    coordinates: LinuxCNC sends it on to motion as it is.

USAGE
    linuxcnc_nurbs.py points RS274_ARGS...      JSON line per NURBS_FEED call:
                                                {"order": k, "points": [[x, y, w], ...]}
    linuxcnc_nurbs.py segments < POINTS.jsonl   JSON line per curve:
                                                {"segments": [{"kind": "arc", "end": [x, y],
                                                  "center": [x, y], "rotation": r} |
                                                 {"kind": "line", "end": [x, y]}, ...]}
    As a module: points(argv, cwd) and segments(curves) (see rs274_motion.py --nurbs).

    When gdb loads this file as its script (gdb -x linuxcnc_nurbs.py) it is the gdb side;
    the environment variable LINUXCNC_NURBS_MODE says which half.
"""

import json
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile

RS274 = "/usr/bin/rs274"
MILLTASK = "/usr/bin/milltask"
NURBS = "NURBS_FEED(int, std::vector<CONTROL_POINT, std::allocator<CONTROL_POINT> >, unsigned int)"
ARC = ("ARC_FEED(int, double, double, double, double, int, double, double, double, double, "
       "double, double, double)")
LINE = ("STRAIGHT_FEED(int, double, double, double, double, double, double, double, double, "
        "double)")


def symbol_offsets(binary, names):
    """Offsets (from the image base) of exported functions, by demangled name."""
    out = subprocess.run(["nm", "-DC", "--defined-only", binary], check=True,
                         stdout=subprocess.PIPE, universal_newlines=True).stdout
    found = {}
    for line in out.splitlines():
        parts = line.split(" ", 2)
        if len(parts) == 3 and parts[1] == "T" and parts[2] in names:
            found[parts[2]] = int(parts[0], 16)
    missing = [n for n in names if n not in found]
    if missing:
        sys.exit("linuxcnc_nurbs: %s does not export %s" % (binary, ", ".join(missing)))
    return found


def run_gdb(binary, args, mode, env_extra, cwd=None):
    gdb = shutil.which("gdb")
    if gdb is None:
        sys.exit("linuxcnc_nurbs: gdb is not installed (Debian: apt install gdb)")
    env = dict(os.environ)
    env.update(env_extra)
    env["LINUXCNC_NURBS_MODE"] = mode
    cmd = [gdb, "-q", "-batch", "-nx", "-x", os.path.abspath(__file__), "--args",
           binary] + list(args)
    proc = subprocess.run(cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          universal_newlines=True, timeout=600)
    return proc


def points(argv, cwd=None):
    """The NURBS_FEED calls of an rs274 run (argv: rs274's arguments)."""
    offs = symbol_offsets(RS274, [NURBS])
    with tempfile.TemporaryDirectory(prefix="linuxcnc_nurbs.") as tmp:
        out = os.path.join(tmp, "points.jsonl")
        run_gdb(RS274, argv, "points",
                {"LINUXCNC_NURBS_OUT": out, "LINUXCNC_NURBS_AT": str(offs[NURBS]),
                 "LINUXCNC_NURBS_BIN": os.path.realpath(RS274)}, cwd=cwd)
        if not os.path.exists(out):
            return []
        with open(out) as fh:
            return [json.loads(line) for line in fh if line.strip()]


def segments(curves):
    """milltask's pieces for each curve ({"order", "points"})."""
    if not curves:
        return []
    offs = symbol_offsets(MILLTASK, [NURBS, ARC, LINE])
    with tempfile.TemporaryDirectory(prefix="linuxcnc_nurbs.") as tmp:
        inp = os.path.join(tmp, "curves.jsonl")
        out = os.path.join(tmp, "segments.jsonl")
        with open(inp, "w") as fh:
            for c in curves:
                fh.write(json.dumps(c) + "\n")
        proc = run_gdb(MILLTASK, [], "segments",
                       {"LINUXCNC_NURBS_IN": inp, "LINUXCNC_NURBS_OUT": out,
                        "LINUXCNC_NURBS_AT": "%d %d %d" % (offs[NURBS], offs[ARC], offs[LINE]),
                        "LINUXCNC_NURBS_BIN": os.path.realpath(MILLTASK)})
        result = []
        if os.path.exists(out):
            with open(out) as fh:
                result = [json.loads(line) for line in fh if line.strip()]
        if len(result) != len(curves):
            sys.exit("linuxcnc_nurbs: milltask segmented %d of %d curves\n%s"
                     % (len(result), len(curves), proc.stderr[-2000:]))
        return result


# ---------------------------------------------------------------------- gdb side

def _gdb_side(gdb):
    mode = os.environ["LINUXCNC_NURBS_MODE"]
    out = open(os.environ["LINUXCNC_NURBS_OUT"], "w")
    binary = os.environ["LINUXCNC_NURBS_BIN"]
    at = [int(v) for v in os.environ["LINUXCNC_NURBS_AT"].split()]
    gdb.execute("set pagination off")
    gdb.execute("set confirm off")
    gdb.execute("starti")  # stdin is /dev/null (see run_gdb)

    def base():
        text = gdb.execute("info proc mappings", to_string=True)
        starts = []
        for line in text.splitlines():
            f = line.split()
            if len(f) >= 5 and f[-1] == binary and f[0].startswith("0x"):
                starts.append(int(f[0], 16))
        return min(starts)

    b = base()
    inf = gdb.selected_inferior()

    def reg(name):
        return int(gdb.selected_frame().read_register(name)) & 0xffffffffffffffff

    def xmm(i):
        return float(gdb.selected_frame().read_register("xmm%d" % i)["v2_double"][0])

    def fin(v):
        return v if math.isfinite(v) else None

    if mode == "points":
        class Capture(gdb.Breakpoint):
            def stop(self):
                vec = reg("rsi")
                k = reg("rdx") & 0xffffffff
                begin, end = struct.unpack("<QQ", bytes(inf.read_memory(vec, 16)))
                vals = struct.unpack("<%dd" % ((end - begin) // 8),
                                     bytes(inf.read_memory(begin, end - begin)))
                pts = [list(vals[i:i + 3]) for i in range(0, len(vals), 3)]
                out.write(json.dumps({"order": k, "points": pts}) + "\n")
                out.flush()
                return False

        Capture("*0x%x" % (b + at[0]), internal=True)
        gdb.execute("continue")
        out.close()
        return

    # segments: NURBS_FEED with ARC_FEED and STRAIGHT_FEED returning at once
    nurbs, arc, line = (b + a for a in at)
    gdb.execute("tbreak main")
    gdb.execute("continue")
    for addr in (arc, line):
        gdb.execute("set *(unsigned char*)0x%x = 0xc3" % addr)
    pieces = []

    class Piece(gdb.Breakpoint):
        def __init__(self, addr, kind):
            super().__init__("*0x%x" % addr, internal=True)
            self.kind = kind

        def stop(self):
            x = [xmm(i) for i in range(4)]
            if self.kind == "arc":
                rot = reg("rsi") & 0xffffffff
                if rot >= 2 ** 31:
                    rot -= 2 ** 32
                pieces.append({"kind": "arc", "end": [fin(x[0]), fin(x[1])],
                               "center": [fin(x[2]), fin(x[3])], "rotation": rot})
            else:
                pieces.append({"kind": "line", "end": [fin(x[0]), fin(x[1])]})
            return False

    Piece(arc, "arc")
    Piece(line, "line")
    with open(os.environ["LINUXCNC_NURBS_IN"]) as fh:
        curves = [json.loads(l) for l in fh if l.strip()]
    for c in curves:
        pts = c["points"]
        n = len(pts)
        gdb.execute("set $pts = (double*)malloc(%d)" % (24 * n))
        for i, (x, y, w) in enumerate(pts):
            for j, v in enumerate((x, y, w)):
                gdb.execute("set $pts[%d] = %r" % (3 * i + j, float(v)))
        gdb.execute("set $vec = (void**)malloc(24)")
        gdb.execute("set $vec[0] = (void*)$pts")
        gdb.execute("set $vec[1] = (void*)($pts + %d)" % (3 * n))
        gdb.execute("set $vec[2] = (void*)($pts + %d)" % (3 * n))
        del pieces[:]
        gdb.execute("call ((void(*)(int, void*, unsigned int))0x%x)(1, $vec, %d)"
                    % (nurbs, int(c["order"])))
        out.write(json.dumps({"segments": pieces}) + "\n")
        out.flush()
    out.close()
    gdb.execute("kill")


def main():
    if len(sys.argv) >= 2 and sys.argv[1] == "points":
        for c in points(sys.argv[2:]):
            print(json.dumps(c))
    elif len(sys.argv) == 2 and sys.argv[1] == "segments":
        curves = [json.loads(l) for l in sys.stdin if l.strip()]
        for s in segments(curves):
            print(json.dumps(s))
    else:
        sys.exit(__doc__)


try:
    import gdb as _gdb  # only inside gdb
except ImportError:
    _gdb = None

if _gdb is not None and os.environ.get("LINUXCNC_NURBS_MODE"):
    _gdb_side(_gdb)
elif __name__ == "__main__":
    main()
