#!/usr/bin/env python3
"""Open a page from disk in headless Chromium and report what a browser saw.

    python3 tools/browser_check.py PAGE.html --screenshot OUT.png [--probe EXPR]
        [--ready EXPR] [--timeout S] [--width PX] [--height PX] [--chromium PATH]
        [--no-webgl]

Drives Chromium over the DevTools protocol on a pipe (--remote-debugging-pipe: JSON
messages ended by a NUL byte on file descriptors 3 and 4), with the standard library
only. It loads the page as file://, waits until the page's `--ready` expression is
truthy (default `window.twinmillReady`), evaluates `--probe` (any JSON value the page
returns), takes a screenshot of the viewport, and prints one JSON object on stdout:

    ready_ms     wall time from navigation to ready (null if never ready)
    ready        the value of the ready expression
    probe        the value of the probe expression
    console      console messages: {level, text}
    exceptions   uncaught exceptions: text
    requests     every URL the page requested (the page itself, data: and blob: URLs too)
    screenshot   the PNG path

Exit status: 0 when the page got ready, 1 when it did not (the JSON still printed), 2 when
Chromium could not be started. It checks nothing itself: the test that runs it decides.
The browser gets a fresh profile, no network services (background networking, component
updates, sync off) and a host resolver that resolves nothing, so a page that tries to reach
the network fails visibly in `requests` instead of waiting. WebGL runs on SwiftShader,
Chromium's software renderer; `--no-webgl` starts Chromium as a browser without WebGL
instead (`--disable-gpu --disable-webgl`).
"""

import argparse
import base64
import fcntl
import json
import os
import pathlib
import select
import shutil
import subprocess
import sys
import tempfile
import time


class Browser:
    """A Chromium process and its DevTools pipe."""

    def __init__(self, chromium, width, height, webgl=True):
        self.profile = tempfile.mkdtemp(prefix="twinmill-chromium-")
        to_child_r, self.to_child = os.pipe()
        self.from_child, from_child_w = os.pipe()

        def fds():
            # DevTools reads commands on fd 3 and writes replies on fd 4. Move both ends
            # above the low numbers first so neither dup2 clobbers the other.
            a = fcntl.fcntl(to_child_r, fcntl.F_DUPFD, 10)
            b = fcntl.fcntl(from_child_w, fcntl.F_DUPFD, 10)
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = [
            chromium,
            "--headless",
            "--remote-debugging-pipe",
            f"--user-data-dir={self.profile}",
            *(
                # WebGL without a GPU: ANGLE on SwiftShader, Chromium's software renderer.
                ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
                if webgl
                # A browser without WebGL (a remote desktop, some virtual machines).
                else ["--disable-gpu", "--disable-webgl"]
            ),
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-quic",
            "--disable-extensions",
            "--disable-default-apps",
            "--mute-audio",
            "--hide-scrollbars",
            "--host-resolver-rules=MAP * ~NOTFOUND",
            f"--window-size={width},{height}",
            "about:blank",
        ]
        if os.geteuid() == 0:
            args.insert(1, "--no-sandbox")
        self.proc = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=fds,
            close_fds=False,
        )
        os.close(to_child_r)
        os.close(from_child_w)
        self.buf = b""
        self.next_id = 0
        self.events = []

    def send(self, method, params=None, session=None):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.to_child, json.dumps(msg).encode() + b"\0")
        return self.next_id

    def read(self, deadline):
        """The next message, or None at the deadline."""
        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            r, _, _ = select.select([self.from_child], [], [], left)
            if not r:
                return None
            chunk = os.read(self.from_child, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed the DevTools pipe")
            self.buf += chunk
        msg, self.buf = self.buf.split(b"\0", 1)
        return json.loads(msg)

    def call(self, method, params=None, session=None, timeout=30.0):
        """Sends a command and waits for its reply; events meanwhile are kept."""
        i = self.send(method, params, session)
        deadline = time.monotonic() + timeout
        while True:
            m = self.read(deadline)
            if m is None:
                raise TimeoutError(method)
            if m.get("id") == i:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def close(self):
        try:
            self.send("Browser.close")
            self.proc.wait(timeout=10)
        except Exception:
            self.proc.kill()
            self.proc.wait()
        for fd in (self.to_child, self.from_child):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)


def remote_text(obj):
    """A console argument as text."""
    if "value" in obj:
        return str(obj["value"])
    return obj.get("description") or obj.get("type", "")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("page")
    ap.add_argument("--screenshot", required=True)
    ap.add_argument("--ready", default="window.twinmillReady")
    ap.add_argument("--probe", default="null")
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=900)
    ap.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    ap.add_argument("--no-webgl", action="store_true")
    a = ap.parse_args()
    url = pathlib.Path(a.page).resolve().as_uri()
    try:
        b = Browser(a.chromium, a.width, a.height, webgl=not a.no_webgl)
    except OSError as e:
        print(json.dumps({"error": f"cannot start {a.chromium}: {e}"}))
        return 2
    out = {
        "page": url,
        "ready_ms": None,
        "ready": None,
        "probe": None,
        "console": [],
        "exceptions": [],
        "requests": [],
        "screenshot": a.screenshot,
    }
    try:
        target = b.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        s = b.call("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        for m in ("Page.enable", "Runtime.enable", "Log.enable", "Network.enable"):
            b.call(m, session=s)
        b.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": a.width, "height": a.height, "deviceScaleFactor": 1, "mobile": False},
            session=s,
        )
        b.events.clear()
        start = time.monotonic()
        b.call("Page.navigate", {"url": url}, session=s)
        deadline = start + a.timeout
        while time.monotonic() < deadline:
            r = b.call(
                "Runtime.evaluate",
                {"expression": a.ready, "returnByValue": True},
                session=s,
            )
            v = r.get("result", {}).get("value")
            if v:
                out["ready_ms"] = round((time.monotonic() - start) * 1000.0, 1)
                out["ready"] = v
                break
            time.sleep(0.05)
        if out["ready"] is not None:
            r = b.call(
                "Runtime.evaluate",
                {"expression": a.probe, "returnByValue": True},
                session=s,
            )
            out["probe"] = r.get("result", {}).get("value")
        shot = b.call("Page.captureScreenshot", {"format": "png"}, session=s)
        pathlib.Path(a.screenshot).write_bytes(base64.b64decode(shot["data"]))
        # Anything still in flight.
        while True:
            m = b.read(time.monotonic() + 0.2)
            if m is None:
                break
            b.events.append(m)
        for e in b.events:
            p = e.get("params", {})
            if e.get("method") == "Runtime.consoleAPICalled":
                text = " ".join(remote_text(x) for x in p.get("args", []))
                out["console"].append({"level": p.get("type"), "text": text})
            elif e.get("method") == "Runtime.exceptionThrown":
                d = p.get("exceptionDetails", {})
                ex = d.get("exception", {})
                out["exceptions"].append(ex.get("description") or d.get("text", ""))
            elif e.get("method") == "Log.entryAdded":
                en = p.get("entry", {})
                out["console"].append({"level": en.get("level"), "text": en.get("text", "")})
            elif e.get("method") == "Network.requestWillBeSent":
                out["requests"].append(p.get("request", {}).get("url", ""))
    finally:
        b.close()
    print(json.dumps(out, indent=1))
    return 0 if out["ready"] is not None else 1


if __name__ == "__main__":
    sys.exit(main())
