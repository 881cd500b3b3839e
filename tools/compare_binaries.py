#!/usr/bin/env python3
"""Runs every job on every built-in scene through two twinmill binaries — the old command
names through OLD, the new verbs through NEW — and compares what they made: JSON reports
equal apart from timings, command names and titles; clouds, meshes, programs, plans,
fragments, traces and pictures byte-identical; stdout the same once the output folders and
command names are aside.

    tools/compare_binaries.py OLD NEW [--quick] [--only SUBSTRING]

Run from the repository's root. Prints one line per job and a tally; exits 1 on any
difference. --quick leaves out the slow jobs (run, identify, correct, design, scan --study,
calibration trials)."""

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

TIMING_KEYS = {"seconds", "timings", "timing", "elapsed_s", "wall_s", "cpu_s", "trial_seconds"}
TEXT_KEYS = {"command", "title"}


def strip(v):
    """The JSON value without timings, command names and titles."""
    if isinstance(v, dict):
        return {
            k: strip(x)
            for k, x in v.items()
            if k not in TEXT_KEYS and k not in TIMING_KEYS and not k.endswith("_seconds")
            and not k.endswith("_ms") and "time" not in k and not k.startswith("timing")
        }
    if isinstance(v, list):
        return [strip(x) for x in v]
    return v


def run(binary, args, cwd):
    p = subprocess.run([binary] + args, cwd=cwd, capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


def files(root):
    return {
        str(p.relative_to(root)): p for p in sorted(Path(root).rglob("*")) if p.is_file()
    }


def same_file(a, b):
    name = a.name
    if name.endswith(".json"):
        try:
            return strip(json.loads(a.read_text())) == strip(json.loads(b.read_text()))
        except ValueError:
            return a.read_bytes() == b.read_bytes()
    if name.endswith(".html"):
        # Pages carry the report (timings) and titles: compared by size within 2 %.
        sa, sb = a.stat().st_size, b.stat().st_size
        return abs(sa - sb) <= 0.02 * max(sa, sb, 1)
    return a.read_bytes() == b.read_bytes()


def normalise(text, dirs):
    for d in dirs:
        text = text.replace(str(d), "<out>")
    # The `wrote` lines name the folders; the `time` lines are timings.
    lines = [
        l
        for l in text.splitlines()
        if "wrote" not in l and l.split()[:1] not in (["time"], ["timings"])
    ]
    try:
        return json.dumps(strip(json.loads(text)), sort_keys=True)
    except ValueError:
        return "\n".join(lines)


RESULTS = []


def compare(label, old, new, old_args, new_args, rename=None):
    """Runs both in fresh folders ({out} in the arguments is the folder) and compares
    stdout, the exit code and every file made (rename: new name -> old name)."""
    with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
        repo = os.getcwd()
        fa = [x.replace("{out}", a).replace("{repo}", repo) for x in old_args]
        fb = [x.replace("{out}", b).replace("{repo}", repo) for x in new_args]
        ca, oa, ea = run(old, fa, a)
        cb, ob, eb = run(new, fb, b)
        problems = []
        if ca != cb:
            problems.append(f"exit {ca} vs {cb} ({ea.strip()[:200]} | {eb.strip()[:200]})")
        if normalise(oa, [a]) != normalise(ob, [b]):
            problems.append("stdout differs")
        fa_, fb_ = files(a), files(b)
        if rename:
            fb_ = {rename.get(k, k): v for k, v in fb_.items()}
        common = sorted(set(fa_) & set(fb_))
        for k in sorted(set(fa_) - set(fb_)):
            problems.append(f"only the old made {k}")
        for k in common:
            if not same_file(fa_[k], fb_[k]):
                problems.append(f"{k} differs")
        status = "same" if not problems else "DIFFERENT: " + "; ".join(problems)
        extra = sorted(set(fb_) - set(fa_))
        note = f" (new also wrote {', '.join(extra)})" if extra else ""
        print(f"{label:<60} exit {ca}, {len(common)} files: {status}{note}", flush=True)
        RESULTS.append(not problems)


def main():
    args = sys.argv[1:]
    quick = "--quick" in args
    only = None
    if "--only" in args:
        only = args[args.index("--only") + 1]
    old, new = [str(Path(x).resolve()) for x in args[:2]]
    repo = Path.cwd()
    scenes = sorted((repo / "scenes").glob("*.toml"))

    def job(label, old_args, new_args=None, slow=False, rename=None):
        if quick and slow:
            return
        if only and only not in label:
            return
        compare(label, old, new, old_args, new_args or old_args, rename)

    for s in scenes:
        text = s.read_text()
        hexapod = 'kind = "hexapod"' in text
        name = s.stem
        sc = str(s)
        cuts = "[stock]" in text
        if cuts:
            job(f"{name}: simulate", ["simulate", sc, "--out", "{out}", "--mesh", "stl,obj,ply"])
            job(f"{name}: simulate --json", ["simulate", sc, "--out", "{out}", "--json"])
        if hexapod:
            job(
                f"{name}: ballbar -> measure --instrument ballbar",
                ["ballbar", sc, "--out", "{out}/t.csv", "--png", "{out}/t.png", "--html", "{out}/t.html"],
                ["measure", sc, "--instrument", "ballbar", "--out", "{out}/t.csv", "--png", "{out}/t.png", "--html", "{out}/t.html"],
            )
            job(
                f"{name}: ballbar --json (YZ, tilt, swing, noise)",
                ["ballbar", sc, "--json", "--plane", "YZ", "--tilt", "20", "--swing", "5", "--noise", "1", "--seed", "7", "--radius", "80", "--out", "{out}/t.csv"],
                ["measure", sc, "--instrument", "ballbar", "--json", "--plane", "YZ", "--tilt", "20", "--swing", "5", "--noise", "1", "--seed", "7", "--radius", "80", "--out", "{out}/t.csv"],
            )
            job(f"{name}: ballbar alias", ["ballbar", sc, "--json", "--direction", "ccw"])
            job(f"{name}: calibrate -> identify", ["calibrate", sc, "--html", "{out}/c.html"], ["identify", sc, "--html", "{out}/c.html"], slow=True)
            job(f"{name}: calibrate --json -> identify --json", ["calibrate", sc, "--json", "--procedure", "jig-free"], ["identify", sc, "--json", "--procedure", "jig-free"], slow=True)
            job(f"{name}: calibrate alias", ["calibrate", sc, "--json"], slow=True)
            job(
                f"{name}: calibrate-design -> design",
                ["calibrate-design", sc, "--out", "{out}/plan.toml", "--circles", "4"],
                ["design", sc, "--out", "{out}", "--circles", "4"],
                slow=True,
                rename={f"{name}-design/plan.toml": "plan.toml"},
            )
            job(f"{name}: calibrate-design alias", ["calibrate-design", sc, "--json", "--circles", "4"], slow=True)
            job(f"{name}: hexapod ik", ["hexapod", "ik", sc, "--pose", "0,0,0,0,0,0"])
            job(f"{name}: hexapod amplification", ["hexapod", "amplification", sc, "--steps", "5", "--z-steps", "2", "--out", "{out}/a.csv", "--png", "{out}/a.png", "--json"])
            job(f"{name}: hexapod homing", ["hexapod", "homing", sc, "--json"])
            job(f"{name}: hexapod pivot", ["hexapod", "pivot", sc, "--json", "--steps", "3"])
            for verb in ["run", "scan", "correct"]:
                job(f"{name}: {verb} (refused)", [verb, sc, "--out", "{out}"])
            continue
        # Serial machines.
        rotary = 'kind = "rotary"' in text
        job(f"{name}: measure laser", ["measure", sc, "--instrument", "laser", "--axis", "X", "--from", "-50", "--to", "50", "--out", "{out}/l.csv", "--png", "{out}/l.png", "--noise", "0.3", "--json"])
        job(f"{name}: measure ballbar", ["measure", sc, "--instrument", "ballbar", "--radius", "50", "--out", "{out}/b.csv", "--png", "{out}/b.png"])
        if rotary:
            job(f"{name}: measure ball-sensor", ["measure", sc, "--instrument", "ball-sensor", "--out", "{out}/s.csv", "--png", "{out}/s.png", "--json"], slow=True)
            job(f"{name}: measure probe", ["measure", sc, "--instrument", "probe", "--out", "{out}/p.csv"], slow=True)
        scanner = "[scanner]" in text
        if scanner:
            job(f"{name}: scan", ["scan", sc, "--out", "{out}"])
            job(f"{name}: run", ["run", sc, "--out", "{out}"], slow=True)
            job(f"{name}: design", ["design", sc, "--out", "{out}", "--params", "dy_AY,gamma_YX" if 'name = "A"' in text else "dx_CY"], slow=True)
        job(f"{name}: identify (refused or run)", ["identify", sc, "--out", "{out}"], slow=True)
        if cuts:
            job(f"{name}: correct", ["correct", sc, "--out", "{out}"], slow=True)

    # Commands without a scene.
    data = str(repo / "tests/data/iso230-2-psi-sls-stage.csv")
    job("evaluate iso230-2", ["evaluate", "iso230-2", data, "--png", "{out}/e.png", "--html", "{out}/e.html"])
    job("evaluate iso230-2 --json", ["evaluate", "iso230-2", data, "--json"])
    job("evaluate ball-sensor", ["evaluate", "ball-sensor", "--html", "{out}/bs.html"])
    job("evaluate ball-sensor --json", ["evaluate", "ball-sensor", "--json", "--tolerance", "2"])
    # A cloud with faces: the built-in scene's scan, made once by the old binary.
    if not only or "fit" in only:
        scanned = tempfile.mkdtemp()
        run(old, ["scan", str(repo / "scenes/mdx50-step.toml"), "--out", scanned], scanned)
        cloud = str(Path(scanned) / "mdx50-step-scan/cloud.ply")
        job("fit the scan's faces", ["fit", cloud])
        job("fit the scan's faces --json", ["fit", cloud, "--json", "--robust"])
        job("fit --plane --seed", ["fit", cloud, "--plane", "--seed", "0,0,0", "--json"])
    for cloud in ["cloudcompare-small.ply", "open3d-small.ply"]:
        job(f"fit {cloud}", ["fit", str(repo / "tests/data" / cloud)])
        job(f"fit {cloud} --sphere --json", ["fit", str(repo / "tests/data" / cloud), "--sphere", "--json"])
    for ngc in sorted((repo / "scenes").glob("*.ngc")):
        job(f"nc motion {ngc.name}", ["nc", "motion", str(ngc), "--events"])
    job("nc bench-program 500", ["nc", "bench-program", "500"])
    job("study plan", ["study", "plan", str(repo / "studies/nine-deviations.toml"), "--shards", "3", "--out", "{out}/m.json"])

    same = sum(RESULTS)
    print(f"{same} of {len(RESULTS)} jobs the same")
    sys.exit(0 if same == len(RESULTS) else 1)


if __name__ == "__main__":
    main()
