"""The robot over a Wi-Fi-like link: the daemon and a 1280x720 30 Hz camera in one network namespace, the
clients in another, the daemon's side of the link shaped by ``tc`` to 20 Mbit/s (tbf: ``rate 20mbit burst
32kbit latency 50ms`` on the daemon's veth, so what the daemon sends to clients crosses at most 20 Mbit/s).

The bar (issue 32): a @foxglove/ws-protocol client gets the camera's ``/compressed`` (made by the daemon's web
part, JPEG quality 80) at >= 25 fps with a median age <= 100 ms while a 100 Hz Float64 keeps >= 95 Hz; the
page in headless Chromium in the client namespace (not loopback: compressed by default) shows >= 20 fps with
an on-screen age <= 150 ms. The camera and the clients share the host's clock, so age = arrival - stamp.

The lab is its own small fixture on ``tests.netns.nsutil.NetnsLab`` (three hosts on a bridge); helper
``fair``'s shaped-link fixture is on its own branch, and the two are meant to be unified when merged.
"""

from __future__ import annotations

import json
import os
import queue
import re
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.integration.daemon.daemonproc import DaemonRun
from tests.netns.nsutil import NetnsLab
from tests.rosenv import Processes
from tests.web.test_web_page import CHROMIUM, NODE, SHOTS, Browser, cwd_env

pytestmark = pytest.mark.root

WEB = Path(__file__).resolve().parent.parent / "web"
TOKEN = "wifi-lab"
W, H, HZ, FAST_HZ = 1280, 720, 30.0, 100.0
#: how long each client is measured, after its first frames
WINDOW = 5.0

needs_clients = pytest.mark.skipif(
    NODE is None or not (WEB / "node_modules" / "playwright-core").is_dir() or not CHROMIUM.exists(),
    reason="node, chromium or the npm packages are missing: scripts/install-system-deps.sh, then "
    "`npm ci --prefix tests/web`",
)


def shape(lab: NetnsLab, host: int, rate: str = "20mbit") -> str:
    """Shape what ``host`` sends (its veth's egress) to ``rate``; returns the qdisc as tc shows it."""
    dev = f"{lab.tag}i{host + 1}"[-15:]
    ns = lab.hosts[host]
    lab.exec_ok(
        ns, ["tc", "qdisc", "add", "dev", dev, "root", "tbf", "rate", rate, "burst", "32kbit", "latency", "50ms"]
    )
    return lab.exec_ok(ns, ["tc", "qdisc", "show", "dev", dev])


@pytest.fixture(scope="module")
def wifi(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[NetnsLab, Processes, str, str]]:
    """The lab, shaped; the daemon and the camera on host 0; returns (lab, procs, foxglove url, page url)."""
    from tests.netns.nsutil import netns_unavailable

    why = netns_unavailable()
    if why is not None:
        pytest.skip(why)
    tmp = tmp_path_factory.mktemp("wifi")
    lab = NetnsLab()
    procs = Processes(tmp)
    run: DaemonRun | None = None
    try:
        lab.setup()
        qdisc = shape(lab, 0)
        assert "tbf" in qdisc and "20Mbit" in qdisc, qdisc
        addr = lab.addrs[0]
        config = tmp / "mrosd.toml"
        config.write_text(
            f'[web]\nhost = "{addr}"\ntoken = "{TOKEN}"\nfoxglove_port = 0\nrosbridge_port = -1\n\n'
            '[[web.images]]\ntopics = ["/camera/*"]\nquality = 80\n'
        )
        # the daemon runs inside host 0: DaemonRun's argv through `ip netns exec` (its notify socket is a path)
        run = DaemonRun(procs, tmp, "--config", str(config), code=_IN_NETNS.format(ns=lab.hosts[0]))
        status = run.ready()
        match = re.search(r"foxglove ws://(\S+?)/", status)
        assert match, status
        env = {
            **cwd_env(),
            "ROS_MASTER_URI": run.uri,
            "ROS_HOSTNAME": "127.0.0.1",
            "PYTHONPATH": os.pathsep.join(sys.path),
        }
        camera = [sys.executable, str(WEB / "stamped_camera.py"), str(W), str(H), str(HZ), str(FAST_HZ)]
        procs.start(lab.argv(0, camera), env, stdout=None, stderr=None)
        base = f"{match.group(1)}/?token={TOKEN}"
        yield lab, procs, f"ws://{base}", f"http://{base}"
    finally:
        if run is not None:
            run.close()
        procs.close()
        lab.teardown()


#: ``python -c`` harness: re-exec the daemon (its arguments as given) inside namespace ``{ns}``
_IN_NETNS = (
    "import os, sys; "
    "os.execvp('ip', ['ip', 'netns', 'exec', '{ns}', sys.executable, '-m', 'mrosd.daemon', *sys.argv[1:]])"
)


def read_lines(proc: subprocess.Popen[bytes], out: queue.Queue[tuple[float, dict[str, Any]]]) -> None:
    assert proc.stdout is not None
    for line in proc.stdout:
        out.put((time.time(), json.loads(line)))


@needs_clients
def test_foxglove_client_behind_20mbit_gets_compressed_camera_and_the_small_topic(
    wifi: tuple[NetnsLab, Processes, str, str],
) -> None:
    lab, procs, ws_url, _ = wifi
    assert NODE is not None
    client = procs.start(
        lab.argv(1, [NODE, str(WEB / "foxglove_client.mjs"), ws_url]), cwd_env(), stdin=subprocess.PIPE
    )
    events: queue.Queue[tuple[float, dict[str, Any]]] = queue.Queue()
    threading.Thread(target=read_lines, args=(client, events), daemon=True).start()

    def send(**cmd: Any) -> None:
        assert client.stdin is not None
        client.stdin.write((json.dumps(cmd) + "\n").encode())
        client.stdin.flush()

    channels: set[str] = set()
    deadline = time.monotonic() + 30
    while not {"/camera/image/compressed", "/fast"} <= channels:
        assert time.monotonic() < deadline, f"channels so far: {channels}"
        try:
            _, ev = events.get(timeout=1)
        except queue.Empty:
            continue
        if ev["event"] == "channel":
            channels.add(ev["topic"])
    send(cmd="subscribe", topic="/camera/image/compressed")
    send(cmd="subscribe", topic="/fast")

    frames: list[tuple[float, float, int]] = []  # (arrival, age, bytes)
    fast: list[float] = []
    start = None
    deadline = time.monotonic() + 30
    while start is None or time.time() < start + 1.0 + WINDOW:  # a second to settle, then the window
        assert time.monotonic() < deadline, f"frames {len(frames)}, fast {len(fast)}"
        try:
            arrival, ev = events.get(timeout=1)
        except queue.Empty:
            continue
        if ev["event"] != "message":
            continue
        if start is None:
            start = arrival
        if arrival < start + 1.0:
            continue
        if ev["topic"] == "/fast":
            fast.append(arrival)
        else:
            secs, nsecs = struct.unpack_from("<II", bytes.fromhex(ev["head"]), 4)
            frames.append((arrival, arrival - (secs + nsecs / 1e9), ev["len"]))
    procs.stop(client)  # the link is the next test's
    fps = len(frames) / WINDOW
    fast_hz = len(fast) / WINDOW
    ages = [age for _, age, _ in frames]
    median_age = statistics.median(ages)
    mbit = sum(n for _, _, n in frames) * 8 / WINDOW / 1e6
    print(f"behind 20 Mbit/s: {fps:.1f} fps, median age {median_age * 1e3:.0f} ms,", end=" ")
    print(f"{mbit:.1f} Mbit/s of JPEG, /fast {fast_hz:.1f} Hz")
    assert fps >= 25, fps
    assert median_age <= 0.100, median_age
    assert fast_hz >= 95, fast_hz


class NetnsBrowser(Browser):
    """tests/web/page_browser.mjs inside a namespace (Browser starts it in ours)."""

    def __init__(self, procs: Processes, lab: NetnsLab, host: int) -> None:
        assert NODE is not None
        self.proc = procs.start(lab.argv(host, [NODE, str(WEB / "page_browser.mjs")]), cwd_env(), stdin=subprocess.PIPE)
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self.log: list[dict[str, Any]] = []
        threading.Thread(target=self._read, daemon=True).start()
        self._ids = 0
        self._wait(lambda m: m.get("event") == "ready", 30)


@needs_clients
def test_the_page_in_the_client_namespace_shows_the_camera_compressed_at_20_fps(
    wifi: tuple[NetnsLab, Processes, str, str],
) -> None:
    lab, procs, _, page = wifi
    browser = NetnsBrowser(procs, lab, 2)
    browser.do("goto", url=page + "#topic=/camera/image")
    browser.until("mrosdPage.state.current && mrosdPage.state.current.topic === '/camera/image/compressed'")
    browser.until("mrosdPage.meter.fps >= 10 && mrosdPage.meter.ageMs !== null", timeout=30)
    samples = []
    for _ in range(10):  # 3 s of what the overlay says
        samples.append(browser.eval("[mrosdPage.meter.fps, mrosdPage.meter.ageMs]"))
        time.sleep(0.3)
    fps = statistics.median(s[0] for s in samples)
    age = statistics.median(s[1] for s in samples)
    text = browser.eval("document.querySelector('#image-overlay').textContent")
    print(f"page behind 20 Mbit/s: {fps} fps, age {age:.0f} ms ({text})")
    SHOTS.mkdir(parents=True, exist_ok=True)
    browser.shot("image_wifi_20mbit.png")
    procs.stop(browser.proc)
    assert fps >= 20, samples
    assert age <= 150, samples
