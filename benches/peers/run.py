#!/usr/bin/env python3
"""Peer benchmarks as whole processes: twinmill and a peer on the same input file,
started in turn (peer, twinmill, peer, twinmill, ...) so that a drift in the machine's
speed hits both alike; prints each command's median wall and CPU seconds and peak memory,
and the median of the pair-by-pair wall-time ratios.

    python3 benches/peers/run.py [--runs N] [--warmup N]
                                 [--only nc|segment|commands|five-axis] [--twinmill PATH]

Pairs (docs/benchmarks.md#peers-as-processes):

* nc: LinuxCNC's `rs274 -g FILE OUT` against `twinmill nc motion FILE --jsonl > OUT` on the
  200,000-block program that `twinmill nc bench-program 200000` writes (G1 with A words,
  every fifth block a G3 with I/J, 6.3 MB).
* segment: Open3D's `segment_plane(distance_threshold=0.1, ransac_n=3,
  num_iterations=1000)` (one plane, in a `python3` process that reads the cloud) against
  `twinmill fit CLOUD --planes` (every planar face, with robust fits) on a 1,266,606-point
  binary PLY laid out like benches/segment.rs: two faces 1 mm apart and a top face,
  0.185 mm spacing, sigma 0.025 mm (written by this script, seed fixed).

And twinmill's own commands as a user runs them (no peer runs these; medians of the runs):

* commands: `twinmill simulate scenes/p1-pocket.toml` (benchmark P1 at 0.05 mm, with its
  report page and part.stl; acceptance: <= 1.5 s wall, <= 400 MB peak, part.stl <= 30 MB)
  and `twinmill run scenes/mdx50-step.toml` (the whole pipeline and its page).
* five-axis: `twinmill simulate` on the simultaneous 5-axis family of benches/data (the
  programs of benches/support/five_axis.rs): the trunnion side cut with the flat and the
  ball end mill (7,203 moves), the blade-like finishing path (1,443 moves) and the hexapod
  machining centre's side cut (720 moves, read pose by pose). Besides each run's wall, CPU
  and peak memory it reads the run's report.json: the sweep's moves per second
  (`sweep.moves` over `timings_s.sweep`), the stock's own size (`stock.memory_mib`) and the
  peak's ratio to it, and prints each figure beside its target (docs/benchmarks.md). It
  reads each scene's name with `tomllib` (Python 3.11 or later).

A peer that is not installed is skipped, saying so. Standard library only (Open3D's own
process imports Open3D). Every command's output goes to a file in a temporary directory,
as a user would write it. CPU seconds and peak memory are the operating system's
accounting of the finished child (`os.wait4`).
"""

import argparse
import json
import os
import random
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def run_once(argv, stdout_path):
    """Runs argv with stdout to stdout_path; returns (wall s, cpu s, peak MiB, exit code)."""
    with open(stdout_path, "wb") as out, open(os.devnull, "rb") as devnull:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, stdin=devnull, stdout=out, stderr=subprocess.PIPE)
        # Read stderr only after the child ends (it writes little); wait4 gives its rusage.
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        err = proc.stderr.read()
        proc.stderr.close()
        proc.returncode = os.waitstatus_to_exitcode(status)
    code = proc.returncode
    if code != 0:
        sys.stderr.write(f"  {' '.join(argv)} exited {code}: {err.decode(errors='replace')[:400]}\n")
    # ru_maxrss is in KiB on Linux.
    return wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0, code


def compare(name, twinmill, peer, runs, warmup, workdir):
    """Runs peer and twinmill in turn; prints medians and the median pair-by-pair ratio."""
    (tw_label, tw_argv, tw_out), (peer_label, peer_argv, peer_out) = twinmill, peer
    for _ in range(warmup):
        run_once(peer_argv, os.path.join(workdir, peer_out))
        run_once(tw_argv, os.path.join(workdir, tw_out))
    tw, pe = [], []
    for _ in range(runs):
        pe.append(run_once(peer_argv, os.path.join(workdir, peer_out)))
        tw.append(run_once(tw_argv, os.path.join(workdir, tw_out)))
    if any(r[3] != 0 for r in tw + pe):
        print(f"{name}: a run failed (see above); no figures")
        return
    med = lambda rs, k: statistics.median(r[k] for r in rs)
    print(f"\n{name} ({runs} pairs, {warmup} warm-up)")
    print(f"  {'command':<44} {'wall s':>8} {'cpu s':>8} {'peak MiB':>9}")
    for label, rs in ((peer_label, pe), (tw_label, tw)):
        print(f"  {label:<44} {med(rs, 0):8.3f} {med(rs, 1):8.3f} {med(rs, 2):9.1f}")
    wall = statistics.median(p[0] / t[0] for p, t in zip(pe, tw))
    cpu = statistics.median(p[1] / t[1] for p, t in zip(pe, tw))
    lo = min(p[0] / t[0] for p, t in zip(pe, tw))
    hi = max(p[0] / t[0] for p, t in zip(pe, tw))
    print(f"  twinmill faster by {wall:.2f}x wall (pairs {lo:.2f}-{hi:.2f}), {cpu:.2f}x CPU")


def repeated(argv, runs, warmup, stdout_path, after=lambda: ()):
    """Runs argv `warmup` times untimed, then `runs` times: each run's (wall s, cpu s, peak
    MiB) followed by what `after` reads of its output; None as soon as a run fails."""
    for _ in range(warmup):
        run_once(argv, stdout_path)
    rs = []
    for _ in range(runs):
        wall, cpu, peak, code = run_once(argv, stdout_path)
        if code != 0:
            return None
        rs.append((wall, cpu, peak, *after()))
    return rs


def solo(name, argv, runs, warmup, workdir, files=()):
    """Runs one twinmill command `runs` times; prints median wall, CPU and peak memory, and
    the size of the files it wrote (paths relative to workdir)."""
    rs = repeated(argv, runs, warmup, os.path.join(workdir, "solo.stdout"))
    if rs is None:
        print(f"{name}: a run failed (see above); no figures")
        return
    med = lambda k: statistics.median(r[k] for r in rs)
    print(f"\n{name} ({runs} runs, {warmup} warm-up)")
    print(f"  {'wall s':>8} {'cpu s':>8} {'peak MiB':>9}   (range of wall {min(r[0] for r in rs):.3f}-{max(r[0] for r in rs):.3f} s)")
    print(f"  {med(0):8.3f} {med(1):8.3f} {med(2):9.1f}")
    for f in files:
        path = os.path.join(workdir, f)
        if os.path.exists(path):
            print(f"  {f}: {os.path.getsize(path) / 1e6:.2f} MB")


# The simultaneous 5-axis family: each scene under benches/data with its targets
# (docs/benchmarks.md), as (comparison, goal) by figure; a figure without a target is left out.
MEMORY = {"peak MiB": ("<=", 300.0), "peak/stock": ("<=", 1.5)}
SIDE_CUT = {"wall s": ("<=", 5.0), "moves/s": (">=", 2000.0), **MEMORY}
FIVE_AXIS = (
    ("trunnion-side-cut.toml", SIDE_CUT),
    ("trunnion-side-cut-ball.toml", SIDE_CUT),
    ("trunnion-blade.toml", {"moves/s": (">=", 3000.0), **MEMORY}),
    ("hexapod-side-cut.toml", {"moves/s": (">=", 1000.0), **MEMORY}),
)


def scene_name(scene):
    """The `name` of the scene file `scene` under benches/data (its output folder's stem)."""
    import tomllib  # Python 3.11's standard library; only this comparison needs it

    with open(os.path.join(REPO, "benches", "data", scene), "rb") as f:
        return tomllib.load(f)["name"]


def five_axis(tw, runs, warmup, workdir):
    """Runs `twinmill simulate` on each scene of FIVE_AXIS `runs` times (after `warmup`),
    in turn scene by scene; prints the medians and each figure against its target."""
    print(f"\nfive-axis: twinmill simulate on benches/data ({runs} runs each, {warmup} warm-up)")
    print(
        f"  {'scene':<28} {'moves':>6} {'wall s':>7} {'cpu s':>7} {'sweep s':>8} "
        f"{'moves/s':>8} {'peak MiB':>9} {'stock MiB':>10} {'peak/stock':>10}"
    )
    verdicts = []
    out = os.path.join(workdir, "five-axis")
    stdout = os.path.join(workdir, "five-axis.stdout")
    for scene, targets in FIVE_AXIS:
        argv = [tw, "simulate", os.path.join(REPO, "benches", "data", scene), "--out", out]
        report = os.path.join(out, f"{scene_name(scene)}-simulate", "report.json")

        def figures_of_run():
            with open(report, encoding="utf-8") as f:
                rep = json.load(f)
            return rep["timings_s"]["sweep"], rep["sweep"]["moves"], rep["stock"]["memory_mib"]

        rs = repeated(argv, runs, warmup, stdout, figures_of_run)
        if rs is None:
            print(f"  {scene}: a run failed (see above); no figures")
            continue
        med = lambda k: statistics.median(r[k] for r in rs)
        wall, cpu, peak, sweep, moves, stock = (med(k) for k in range(6))
        figures = {
            "wall s": wall,
            "moves/s": statistics.median(r[4] / r[3] for r in rs),
            "peak MiB": peak,
            "peak/stock": statistics.median(r[2] / r[5] for r in rs),
        }
        print(
            f"  {scene:<28} {moves:6.0f} {wall:7.2f} {cpu:7.2f} {sweep:8.2f} "
            f"{figures['moves/s']:8.0f} {peak:9.1f} {stock:10.1f} {figures['peak/stock']:10.2f}"
        )
        for what, (sign, goal) in targets.items():
            value = figures[what]
            met = value <= goal if sign == "<=" else value >= goal
            verdicts.append(
                f"  {scene:<28} {what:<10} {value:9.2f} (target {sign} {goal:g}): {'met' if met else 'NOT MET'}"
            )
    print("  targets:")
    for v in verdicts:
        print(v)


def write_cloud(path):
    """The segmentation cloud of benches/segment.rs as binary little-endian PLY (doubles):
    rows 0-383 face B (y = 1, z < 0), 384-767 face A (y = 0, z > 0), 768-1151 the top face
    (z = 71.04); Gaussian noise sigma 0.025 mm along the viewing ray (0, 308, -80)."""
    n, row, face_rows, pitch, sigma = 1_266_606, 1_100, 384, 0.185, 0.025
    norm = (308.0**2 + 80.0**2) ** 0.5
    vy, vz = 308.0 / norm, -80.0 / norm
    height = face_rows * pitch
    rng = random.Random(2002)
    buf = bytearray()
    pack = struct.Struct("<3d").pack
    for i in range(n):
        r, c = divmod(i, row)
        x = (c + 0.5) * pitch
        t = (r % face_rows + 0.5) * pitch
        f = r // face_rows
        if f == 0:
            p = (x, 1.0, t - height)
        elif f == 1:
            p = (x, 0.0, t)
        else:
            p = (x, t, height)
        g = sigma * rng.gauss(0.0, 1.0)
        buf += pack(p[0], p[1] + vy * g, p[2] + vz * g)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment benches/peers/run.py segmentation cloud, mm\n"
        f"element vertex {n}\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(buf)


OPEN3D = (
    "import sys, open3d as o3d\n"
    "pc = o3d.io.read_point_cloud(sys.argv[1])\n"
    "model, inliers = pc.segment_plane(distance_threshold=0.1, ransac_n=3, num_iterations=1000)\n"
    "print(len(pc.points), len(inliers), *model)\n"
)


def has_open3d():
    probe = subprocess.run(
        [sys.executable, "-c", "import open3d"], capture_output=True, stdin=subprocess.DEVNULL
    )
    return probe.returncode == 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="timed pairs per comparison (default 5)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed pairs first (default 1)")
    ap.add_argument(
        "--only", choices=["nc", "segment", "commands", "five-axis"], help="run one comparison"
    )
    ap.add_argument(
        "--twinmill",
        default=os.path.join(REPO, "target", "release", "twinmill"),
        help="the twinmill binary (default: target/release/twinmill; cargo build --release)",
    )
    args = ap.parse_args()
    if not (os.path.isfile(args.twinmill) and os.access(args.twinmill, os.X_OK)):
        sys.exit(f"no twinmill binary at {args.twinmill}: run cargo build --release first")
    if args.runs < 1 or args.warmup < 0:
        sys.exit("--runs must be at least 1 and --warmup at least 0")
    tw = args.twinmill
    print(f"machine: {os.cpu_count()} cores; load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory(prefix="twinmill-peers-") as work:
        if args.only in (None, "nc"):
            rs274 = shutil.which("rs274")
            if rs274 is None:
                print("\nnc: LinuxCNC's rs274 is not installed (apt-get install linuxcnc-uspace); skipped")
            else:
                ngc = os.path.join(work, "bench.ngc")
                with open(ngc, "wb") as f:
                    subprocess.run([tw, "nc", "bench-program", "200000"], stdout=f, check=True)
                compare(
                    f"nc: 200,000-block program ({os.path.getsize(ngc) / 1e6:.1f} MB)",
                    ("twinmill nc motion FILE --jsonl > OUT", [tw, "nc", "motion", ngc, "--jsonl"], "tw.jsonl"),
                    ("rs274 -g FILE OUT", [rs274, "-g", ngc, os.path.join(work, "rs.out")], "rs.stdout"),
                    args.runs,
                    args.warmup,
                    work,
                )
        if args.only in (None, "segment"):
            if not has_open3d():
                print(f"\nsegment: Open3D is not installed for {sys.executable} (pip install open3d); skipped")
            else:
                cloud = os.path.join(work, "cloud.ply")
                write_cloud(cloud)
                compare(
                    "segment: 1,266,606-point cloud (binary PLY)",
                    ("twinmill fit CLOUD --planes", [tw, "fit", cloud, "--planes"], "tw.txt"),
                    (
                        "open3d segment_plane, 1000 iterations",
                        [sys.executable, "-c", OPEN3D, cloud],
                        "o3d.txt",
                    ),
                    args.runs,
                    args.warmup,
                    work,
                )
        if args.only in (None, "commands"):
            out = os.path.join(work, "out")
            solo(
                "commands: twinmill simulate scenes/p1-pocket.toml (P1 at 0.05 mm)",
                [tw, "simulate", os.path.join(REPO, "scenes", "p1-pocket.toml"), "--out", out],
                args.runs,
                args.warmup,
                work,
                files=("out/p1-pocket-simulate/part.stl", "out/p1-pocket-simulate/report.html"),
            )
            solo(
                "commands: twinmill run scenes/mdx50-step.toml",
                [tw, "run", os.path.join(REPO, "scenes", "mdx50-step.toml"), "--out", out],
                args.runs,
                args.warmup,
                work,
                files=("out/mdx50-step/report.html",),
            )
        if args.only in (None, "five-axis"):
            five_axis(tw, args.runs, args.warmup, work)
    print(f"\nload average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
