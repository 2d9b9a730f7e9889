"""Benchmark of the live map: update rate and latency at the page, CPU of the map server, page weight.

Run from the repository root (needs Debian's ``chromium`` and ``pip install playwright``)::

    python benchmarks/bench_map.py                 # N = 8 and N = 100, 20 s windows
    python benchmarks/bench_map.py --n 8 --window-s 10
    python benchmarks/bench_map.py --screenshot docs/figures/map.png   # the picture in docs/operator.md

For each N: a wall-clock mission ``swarmseek run --n N --speedup 1 --map 127.0.0.1:0
--zenoh-listen EP`` (its state publication at 10 Hz) and, in a process of its own, a second map
``swarmseek map swarmseek --zenoh-connect EP`` with a headless Chromium page open on it. Over the
window (started once every vehicle's marker is on the page) it prints:

* the page's update rate (snapshots received per wall second);
* its latency behind the state publication: the page's ``Date.now()`` at each snapshot minus the
  snapshot's ``published_wall_s`` (the publisher's ``time.time()`` just before the zenoh put;
  same host): zenoh, the map server, the server-sent event and the page's parsing, median and p99;
* the CPU of the map server process (user + system time over the window, % of one core);
* the snapshot's size (bytes of JSON) and the page's weight (its HTML, script and styles, raw and
  gzip-compressed; nothing else is loaded unless a tile URL is given).
"""
from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (and its threads)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Lines(threading.Thread):
    def __init__(self, stream):
        super().__init__(daemon=True)
        self.stream, self.lines = stream, []
        self.start()

    def run(self):
        for line in self.stream:
            self.lines.append(line)

    def url(self, what: str, timeout_s: float = 120.0) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in self.lines:
                m = re.search(r"(http://\S+/)", line) if what in line else None
                if m:
                    return m.group(1)
            time.sleep(0.1)
        raise RuntimeError(f"no {what!r} line: {''.join(self.lines)[-2000:]}")


def page_weight() -> dict:
    static = ROOT / "mission" / "telemetry" / "map_static"
    raw = {p.name: p.read_bytes() for p in sorted(static.iterdir())}
    return {"bytes": sum(len(b) for b in raw.values()), "gzip_bytes": sum(len(gzip.compress(b)) for b in raw.values()),
            "files": {k: len(v) for k, v in raw.items()}}


def measure(n: int, window_s: float, chromium: str) -> dict:
    from playwright.sync_api import sync_playwright

    ep = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        mission = subprocess.Popen([sys.executable, "-m", "mission", "run", "--n", str(n), "--speedup", "1",
                                    "--map", "127.0.0.1:0", "--zenoh-listen", ep, "--json", "--no-tlog",
                                    "--log-dir", tmp], env=env, cwd=ROOT, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.PIPE, text=True)
        Lines(mission.stderr).url("live map at")
        viewer = subprocess.Popen([sys.executable, "-m", "mission", "map", "swarmseek", "--zenoh-connect", ep,
                                   "--bind", "127.0.0.1:0", "--read-only"], env=env, cwd=ROOT,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            url = Lines(viewer.stderr).url("serving")
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox"])
                page = browser.new_page(bypass_csp=True)
                page.goto(url)
                page.wait_for_function(f"document.querySelectorAll('circle.vehicle[id^=veh-]').length == {n}",
                                       timeout=300_000)
                page.evaluate("() => { window.swarmseekMap.latencies_ms = []; window.swarmseekMap.updates = 0; }")
                cpu0, t0 = cpu_s(viewer.pid), time.monotonic()
                time.sleep(window_s)  # a benchmark's measurement window, not a wait for a condition
                cpu1, t1 = cpu_s(viewer.pid), time.monotonic()
                got = page.evaluate("() => [window.swarmseekMap.updates, window.swarmseekMap.latencies_ms,"
                                    " JSON.stringify(window.swarmseekMap.state).length]")
                browser.close()
        finally:
            for p in (viewer, mission):
                p.terminate()
                p.wait(timeout=60)
    updates, lat, state_bytes = got
    lat = sorted(lat)
    return {"n": n, "window_s": round(t1 - t0, 2), "updates_per_s": round(updates / (t1 - t0), 2),
            "latency_ms_median": round(statistics.median(lat), 1) if lat else None,
            "latency_ms_p99": round(lat[min(len(lat) - 1, int(0.99 * len(lat)))], 1) if lat else None,
            "map_cpu_pct": round(100 * (cpu1 - cpu0) / (t1 - t0), 1), "state_bytes": state_bytes}


def screenshot(path: Path, chromium: str) -> None:
    """A picture of the page during a mission (``run --speedup 2 --seed 3 --map``), taken once the
    seek has an estimate with its region and 8 iterations."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        mission = subprocess.Popen([sys.executable, "-m", "mission", "run", "--speedup", "2", "--seed", "3",
                                    "--map", "127.0.0.1:0", "--json", "--no-tlog", "--log-dir", tmp],
                                   env=dict(os.environ, PYTHONPATH=str(ROOT)), cwd=ROOT,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            url = Lines(mission.stderr).url("live map at")
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1400, "height": 900}, bypass_csp=True)
                page.goto(url)
                page.wait_for_function("window.swarmseekMap.state && window.swarmseekMap.state.iteration >= 8 && "
                                       "window.swarmseekMap.state.estimate_region95_m", timeout=300_000)
                page.screenshot(path=str(path))
                browser.close()
        finally:
            mission.terminate()
            mission.wait(timeout=60)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, action="append", default=None, help="vehicles (repeatable; default 8 and 100)")
    parser.add_argument("--window-s", type=float, default=20.0)
    parser.add_argument("--chromium", default=shutil.which("chromium") or "/usr/bin/chromium")
    parser.add_argument("--screenshot", type=Path, default=None, metavar="PNG",
                        help="only take the page's picture during a mission (docs/figures/map.png)")
    args = parser.parse_args()
    if args.screenshot is not None:
        screenshot(args.screenshot, args.chromium)
        return
    print(json.dumps({"page_weight": page_weight()}))
    for n in args.n or [8, 100]:
        print(json.dumps(measure(n, args.window_s, args.chromium)), flush=True)


if __name__ == "__main__":
    main()
