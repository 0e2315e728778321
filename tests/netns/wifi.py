"""The Wi-Fi lab: the robot (daemon + scene) in one network namespace, the operator's clients in another, joined
by one veth pair whose robot-to-client direction is shaped to a Wi-Fi-like rate with ``tc`` tbf.

Reusable by any test of the web part over a slow link (``tests/netns/test_wifi_*.py``)::

    with WifiScene(tmp_path) as scene:              # namespaces, shaped link, daemon, scene publisher
        fox = scene.foxglove(shaped=True)           # @foxglove/ws-protocol client in the client namespace
        fox.subscribe(CAMERA, ODOM, FLOAT)
        got = fox.collect(seconds=4.0)              # per topic: count, rate, ages
        scene.foxglove(shaped=False)                # the same client on the robot's loopback (not shaped)

The shaping (``tbf rate 20mbit burst 32kb latency 50ms`` on the robot's end of the pair): the burst is what
the bucket lets through at line rate, 32 KB = 13 ms of the link, about what a Wi-Fi aggregate carries; the
``latency`` bounds the qdisc's queue to 50 ms of the link (125 KB), about an access point's buffer: beyond it
packets drop and TCP backs off, as on a real link. Only that direction is shaped (the bridges' data flows that
way; the client's acks and requests are small). Both namespaces exist only for the test: no address leaks to
the caller's namespace, and teardown deletes them (and so every process, veth and qdisc) even on failure.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import random
import re
import statistics
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

from tests.integration.daemon.daemonproc import NotifyListener, daemon_env
from tests.netns.nsutil import MASTER_PORT, delete_namespaces, netns_unavailable
from tests.netns.scene import CAMERA, FLOAT, ODOM
from tests.rosenv import Processes

__all__ = ["CAMERA", "FLOAT", "ODOM", "TOKEN", "FoxgloveProbe", "ShapedLink", "TopicStats", "WifiScene"]

ROOT = Path(__file__).resolve().parents[2]
FOXGLOVE_CLIENT = ROOT / "tests" / "web" / "foxglove_client.mjs"
SCENE = Path(__file__).resolve().parent / "scene.py"
TOKEN = "wifi-lab-token-0123456789"


def _ip(*args: str) -> str:
    done = subprocess.run(["ip", *args], capture_output=True, check=False, timeout=10)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)} failed: {done.stderr.decode().strip()}")
    return done.stdout.decode()


@dataclass
class ShapedLink:
    """Two namespaces, ``robot`` and ``client``, joined by a veth pair shaped from robot to client."""

    rate: str = "20mbit"
    burst: str = "32kb"
    latency: str = "50ms"
    tag: str = field(default_factory=lambda: f"wf{os.getpid() % 10000}{random.randrange(100, 1000)}")
    net: str = field(default_factory=lambda: f"10.{random.randrange(200, 250)}.{random.randrange(1, 255)}")
    _made: list[str] = field(default_factory=list)

    @property
    def robot(self) -> str:
        return f"{self.tag}r"

    @property
    def client(self) -> str:
        return f"{self.tag}c"

    @property
    def robot_addr(self) -> str:
        return f"{self.net}.1"

    @property
    def client_addr(self) -> str:
        return f"{self.net}.2"

    @property
    def robot_dev(self) -> str:
        return f"{self.tag}a"[-15:]

    def setup(self) -> None:
        for ns in (self.robot, self.client):
            _ip("netns", "add", ns)
            self._made.append(ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        peer = f"{self.tag}b"[-15:]
        # made inside the robot's namespace and moved: the pair never appears in the caller's namespace
        _ip("-n", self.robot, "link", "add", self.robot_dev, "type", "veth", "peer", "name", peer)
        _ip("-n", self.robot, "link", "set", peer, "netns", self.client)
        for ns, dev, addr in ((self.robot, self.robot_dev, self.robot_addr), (self.client, peer, self.client_addr)):
            _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
        self.shape(self.rate)

    def shape(self, rate: str) -> None:
        """Set (or change) the robot-to-client rate."""
        tbf = ["rate", rate, "burst", self.burst, "latency", self.latency]
        done = subprocess.run(
            self.argv(self.robot, ["tc", "qdisc", "replace", "dev", self.robot_dev, "root", "tbf", *tbf]),
            capture_output=True,
            check=False,
            timeout=10,
        )
        if done.returncode != 0:
            raise RuntimeError(f"tc tbf failed: {done.stderr.decode().strip()}")
        self.rate = rate

    def sent_bytes(self) -> int:
        """Bytes the robot's end of the link has sent so far (what went over the air)."""
        out = _ip("-n", self.robot, "-s", "-j", "link", "show", self.robot_dev)
        return int(json.loads(out)[0]["stats64"]["tx"]["bytes"])

    def argv(self, ns: str, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside namespace ``ns`` (``self.robot`` or ``self.client``), keeping its pid."""
        return ["ip", "netns", "exec", ns, *argv]

    def teardown(self) -> None:
        delete_namespaces(self._made)


def lab_unavailable() -> str | None:
    """Why the Wi-Fi lab cannot run here, or None."""
    why = netns_unavailable()
    if why is not None:
        return why
    import shutil

    if shutil.which("tc") is None:
        return "iproute2's `tc` is not installed"
    if shutil.which("node") is None or not (ROOT / "tests" / "web" / "node_modules").exists():
        return "node and tests/web/node_modules (npm install) are needed for the Foxglove client"
    return None


@dataclass
class TopicStats:
    """What one client received of one topic over a collection window."""

    count: int
    rate: float
    #: now minus the message's stamp at arrival, seconds, in arrival order
    ages: list[float]
    #: the stamps (s) in arrival order
    stamps: list[float]

    @property
    def median_age(self) -> float:
        return statistics.median(self.ages) if self.ages else float("inf")

    @property
    def p90_age(self) -> float:
        return statistics.quantiles(self.ages, n=10)[-1] if len(self.ages) >= 2 else self.median_age


ROSLIBPY_CLIENT = Path(__file__).resolve().parent / "roslibpy_wifi.py"


def _stamp(topic: str, head: bytes) -> float | None:
    """The publish time the scene wrote into a message's first bytes (header.stamp, or the Float64's value)."""
    if topic == FLOAT and len(head) >= 8:
        return float(struct.unpack_from("<d", head)[0])
    if len(head) >= 12:
        secs, nsecs = struct.unpack_from("<II", head, 4)
        return secs + nsecs * 1e-9
    return None


class FoxgloveProbe:
    """tests/web/foxglove_client.mjs (the real @foxglove/ws-protocol client) run by ``argv``; events read in a
    thread into a queue; ``collect`` turns the message events of a window into ``TopicStats``."""

    def __init__(self, procs: Processes, argv: list[str]) -> None:
        self.procs = procs
        self.proc = procs.start(argv, stdin=subprocess.PIPE)
        self.events: queue.Queue[dict[str, Any]] = queue.Queue()
        self.channels: dict[str, dict[str, Any]] = {}
        self.opened: dict[str, Any] = {}
        self.statuses: list[dict[str, Any]] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with contextlib.suppress(ValueError):
                self.events.put(json.loads(line))
        self.events.put({"event": "eof"})

    def send(self, **cmd: Any) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write((json.dumps(cmd) + "\n").encode())
        self.proc.stdin.flush()

    def wait(self, pred: Callable[[dict[str, Any]], bool], timeout: float = 20.0) -> dict[str, Any]:
        """The first event for which ``pred`` holds (events before it are noted, not kept)."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"no such event within {timeout} s")
            try:
                ev = self.events.get(timeout=remaining)
            except queue.Empty:
                raise TimeoutError(f"no such event within {timeout} s") from None
            self._note(ev)
            if ev.get("event") == "eof":
                err = self.proc.stderr.read().decode() if self.proc.stderr is not None else ""
                raise RuntimeError(f"the Foxglove client exited: {err[-2000:]}")
            if pred(ev):
                return ev

    def _note(self, ev: dict[str, Any]) -> None:
        kind = ev.get("event")
        if kind == "channel":
            self.channels[ev["topic"]] = ev
        elif kind == "open":
            self.opened = ev
        elif kind == "status":
            self.statuses.append(ev)

    def subscribe(self, *topics: str, timeout: float = 20.0) -> None:
        """Wait for each topic's channel, then subscribe to it."""
        for topic in topics:
            if topic not in self.channels:
                self.wait(lambda ev, t=topic: ev.get("event") == "channel" and ev.get("topic") == t, timeout)
            self.send(cmd="subscribe", topic=topic)
            self.wait(lambda ev, t=topic: ev.get("event") == "subscribed" and ev.get("topic") == t, timeout)

    def collect(self, seconds: float, warmup: float = 0.0, settle: float = 1.5) -> dict[str, TopicStats]:
        """What arrived of the messages published during ``seconds`` (after ``warmup``), by topic.

        Messages are counted by their publish stamp, not by their arrival: behind a slow link small messages
        arrive in bursts (each after a camera frame), and a window of arrivals would cut a burst at either end.
        Collection goes on for ``settle`` seconds after the window, for the messages still in flight.
        """
        start = time.time() + warmup
        end = start + seconds
        stop = time.monotonic() + warmup + seconds + settle
        got: dict[str, list[tuple[float, float]]] = {}
        while True:
            remaining = stop - time.monotonic()
            if remaining <= 0:
                break
            try:
                ev = self.events.get(timeout=remaining)
            except queue.Empty:
                break
            self._note(ev)
            if ev.get("event") != "message":
                continue
            stamp = ev["stamp"] if "stamp" in ev else _stamp(ev["topic"], bytes.fromhex(ev["head"]))
            if stamp is not None and start <= stamp < end:
                at = ev["at"] if "stamp" in ev else ev["at"] / 1000.0  # roslibpy's seconds, node's ms
                got.setdefault(ev["topic"], []).append((at - stamp, stamp))
        return {
            topic: TopicStats(len(rows), len(rows) / seconds, [a for a, _ in rows], [s for _, s in rows])
            for topic, rows in got.items()
        }

    def close(self) -> None:
        self.procs.stop(self.proc)


class WifiScene:
    """The shaped link, the daemon in the robot's namespace (web part on the robot's address and its loopback,
    with ``TOKEN``) and the scene publisher; everything stopped and deleted on exit."""

    def __init__(self, tmp: Path, rate: str = "20mbit", **daemon_env_extra: str) -> None:
        self.tmp = tmp
        self.link = ShapedLink(rate=rate)
        self.procs = Processes(tmp)
        self._env_extra = daemon_env_extra
        self.notify: NotifyListener | None = None
        self.daemon: subprocess.Popen[bytes] | None = None
        self.foxglove_port = 0
        self.rosbridge_port = 0

    def __enter__(self) -> WifiScene:
        try:
            self._start()
        except BaseException:
            self.close()
            raise
        return self

    def _start(self) -> None:
        self.link.setup()
        self.notify = NotifyListener(self.tmp)
        log = (self.tmp / "daemon.log").open("wb")
        env = daemon_env(
            self.tmp,
            self.notify.path,
            MROSD_WEB_HOST=f"{self.link.robot_addr},127.0.0.1",
            MROSD_WEB_TOKEN=TOKEN,
            **self._env_extra,
        )
        self.daemon = self.procs.start(
            self.link.argv(self.link.robot, [sys.executable, "-m", "mrosd.daemon", "--port", str(MASTER_PORT)]),
            env,
            stdout=subprocess.DEVNULL,
            stderr=log.fileno(),
        )
        log.close()
        status = "".join(self.notify.until("READY=1", 30.0))
        fox = re.search(r"foxglove ws://\S*?:(\d+)/", status)
        ros = re.search(r"rosbridge ws://\S*?:(\d+)/", status)
        assert fox is not None and ros is not None, status
        self.foxglove_port, self.rosbridge_port = int(fox.group(1)), int(ros.group(1))
        scene = self.procs.start(
            self.link.argv(self.link.robot, [sys.executable, str(SCENE), f"http://127.0.0.1:{MASTER_PORT}/"]),
            {**env, "ROS_HOSTNAME": "127.0.0.1"},
            stderr=subprocess.DEVNULL,
        )
        assert scene.stdout is not None
        line = scene.stdout.readline()
        assert line.strip() == b"ready", f"the scene did not start: {line!r}"
        self.scene = scene

    def daemon_log(self) -> str:
        return (self.tmp / "daemon.log").read_text(errors="replace")

    def host(self, shaped: bool) -> str:
        return self.link.robot_addr if shaped else "127.0.0.1"

    def url(self, port: int, shaped: bool) -> str:
        return f"ws://{self.host(shaped)}:{port}/?token={TOKEN}"

    def client_argv(self, argv: Sequence[str], shaped: bool = True) -> list[str]:
        """``argv`` run where the client sits: the client's namespace (shaped) or the robot's (loopback)."""
        return self.link.argv(self.link.client if shaped else self.link.robot, argv)

    def page_url(self, shaped: bool = True) -> str:
        """The page (served on the Foxglove port), with the token."""
        return f"http://{self.host(shaped)}:{self.foxglove_port}/?token={TOKEN}"

    def browser(self, shaped: bool = True) -> Any:
        """tests/web/page_browser.mjs (headless Chromium) started where the client sits: a
        ``tests.web.test_web_page.Browser`` (``do``, ``eval``, ``until``, ``shot``), stopped with the scene."""
        from tests.web.test_web_page import NODE, Browser, cwd_env

        assert NODE is not None
        argv = self.client_argv([NODE, str(ROOT / "tests" / "web" / "page_browser.mjs")], shaped)
        procs = self.procs

        class NetnsBrowser(Browser):
            def __init__(self) -> None:  # Browser's, with node started in the client's namespace
                self.proc = procs.start(argv, cwd_env(), stdin=subprocess.PIPE)
                self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
                self.log: list[dict[str, Any]] = []
                threading.Thread(target=self._read, daemon=True).start()
                self._ids = 0
                self._wait(lambda m: m.get("event") == "ready", 30)

        return NetnsBrowser()

    def foxglove(self, shaped: bool = True, deflate: bool = True) -> FoxgloveProbe:
        """A started @foxglove/ws-protocol client (offering permessage-deflate unless ``deflate`` is False)."""
        argv = ["node", str(FOXGLOVE_CLIENT), self.url(self.foxglove_port, shaped)]
        if not deflate:
            argv.append("--no-deflate")
        probe = FoxgloveProbe(self.procs, self.client_argv(argv, shaped))
        probe.wait(lambda ev: ev.get("event") == "open")
        return probe

    def roslibpy(self, topics: dict[str, str], shaped: bool = True) -> FoxgloveProbe:
        """roslibpy (asyncio transport, offering permessage-deflate) subscribed to ``topics`` (name: type) with
        ``compression: cbor`` on the rosbridge port; the same event reader as the Foxglove client's."""
        argv = [sys.executable, str(ROSLIBPY_CLIENT), self.host(shaped), str(self.rosbridge_port), TOKEN]
        probe = FoxgloveProbe(self.procs, self.client_argv([*argv, *(f"{t}:{ty}" for t, ty in topics.items())], shaped))
        probe.wait(lambda ev: ev.get("event") == "subscribed")
        return probe

    def daemon_cpu(self) -> float:
        """CPU seconds the daemon has used so far."""
        assert self.daemon is not None
        fields = Path(f"/proc/{self.daemon.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def close(self) -> None:
        self.procs.close()
        if self.notify is not None:
            self.notify.close()
        self.link.teardown()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


@contextlib.contextmanager
def wifi_scene(tmp: Path, rate: str = "20mbit", **env: str) -> Iterator[WifiScene]:
    """``WifiScene`` as a generator for fixtures; skips (pytest) when the lab cannot run here."""
    import pytest

    why = lab_unavailable()
    if why is not None:
        pytest.skip(why)
    with WifiScene(tmp, rate, **env) as scene:
        yield scene
