"""Three network namespaces on a private /24, made and removed by the test (root only).

Layout: a hub namespace holds a bridge; each host namespace ``h1..h3`` is joined to it by a veth pair and gets
``<net>.1``, ``<net>.2``, ``<net>.3``. The /24 is picked at random in 10.0.0.0/8 and exists only inside these
namespaces: no address is configured in the caller's namespace, no route leads out, so no packet of a test can
reach any other network. Every namespace (and with it every veth and the bridge) is deleted at teardown, even
when the test failed.
"""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import signal
import subprocess
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

HOSTS = 3
#: The master port of every daemon in the labs (each robot in its own namespace, so the default port is free).
MASTER_PORT = 11311
#: The Zenoh port the labs' daemons and routers listen on (rmw_zenohd's).
ZENOH_PORT = 7447


def netns_unavailable() -> str | None:
    """Why these tests cannot run here, or None when they can."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "iproute2 (`ip`) is not installed"
    probe = f"mrtprobe{os.getpid() % 100000}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, check=False)
    if made.returncode != 0:
        return f"`ip netns add` fails here: {made.stderr.decode().strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, check=False)
    return None


def delete_namespaces(made: list[str]) -> None:
    """Kill what runs in each namespace of ``made`` and delete them, newest first; ``made`` is emptied."""
    for ns in reversed(made):
        # only processes this test started live in these namespaces; any left would keep the veth alive
        pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, check=False, timeout=10)
        for pid in pids.stdout.split():
            with contextlib.suppress(ProcessLookupError, ValueError):
                os.kill(int(pid), signal.SIGKILL)
        subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False, timeout=10)
    made.clear()


def lab_daemon_config(path: Path, sections: str) -> Path:
    """Write an mrosd.toml for one daemon of a lab to ``path``: the master on loopback at MASTER_PORT, no IXM, no
    rosout, then ``sections`` (TOML text: the part under test)."""
    head = f"""
    [master]
    host = "127.0.0.1"
    port = {MASTER_PORT}
    [ixm]
    enabled = false
    [rosout]
    enabled = false
    """
    path.write_text(textwrap.dedent(head) + sections)
    return path


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


@dataclass
class NetnsLab:
    """The namespaces of one test: ``hosts[i]`` is the namespace name, ``addrs[i]`` its address."""

    tag: str = field(default_factory=lambda: f"mrt{os.getpid() % 10000}{random.randrange(100, 1000)}")
    net: str = field(default_factory=lambda: f"10.{random.randrange(200, 250)}.{random.randrange(1, 255)}")
    hosts: list[str] = field(default_factory=list)
    addrs: list[str] = field(default_factory=list)
    _made: list[str] = field(default_factory=list)

    @property
    def hub(self) -> str:
        return f"{self.tag}hub"

    def setup(self) -> None:
        _ip("netns", "add", self.hub)
        self._made.append(self.hub)
        self.exec_ok(self.hub, ["ip", "link", "set", "lo", "up"])
        self.exec_ok(self.hub, ["ip", "link", "add", "br0", "type", "bridge"])
        self.exec_ok(self.hub, ["ip", "link", "set", "br0", "up"])
        for i in range(1, HOSTS + 1):
            ns = f"{self.tag}h{i}"
            _ip("netns", "add", ns)
            self._made.append(ns)
            inner, outer = f"{self.tag}i{i}"[-15:], f"{self.tag}o{i}"[-15:]
            # made directly inside the host namespace, so the pair never appears in the caller's namespace
            self.exec_ok(ns, ["ip", "link", "add", inner, "type", "veth", "peer", "name", outer])
            self.exec_ok(ns, ["ip", "link", "set", outer, "netns", self.hub])
            self.exec_ok(self.hub, ["ip", "link", "set", outer, "master", "br0"])
            self.exec_ok(self.hub, ["ip", "link", "set", outer, "up"])
            addr = f"{self.net}.{i}"
            self.exec_ok(ns, ["ip", "link", "set", "lo", "up"])
            self.exec_ok(ns, ["ip", "addr", "add", f"{addr}/24", "dev", inner])
            self.exec_ok(ns, ["ip", "link", "set", inner, "up"])
            self.hosts.append(ns)
            self.addrs.append(addr)

    def exec_ok(self, ns: str, argv: Sequence[str], timeout: float = 10) -> str:
        done = subprocess.run(["ip", "netns", "exec", ns, *argv], capture_output=True, check=False, timeout=timeout)
        if done.returncode != 0:
            raise RuntimeError(f"in {ns}: {' '.join(argv)} failed: {done.stderr.decode().strip()}")
        return done.stdout.decode()

    def argv(self, host: int, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside host namespace ``host`` (0-based); `ip netns exec` execs it, keeping the pid."""
        return ["ip", "netns", "exec", self.hosts[host], *argv]

    def teardown(self) -> None:
        delete_namespaces(self._made)

    def leftovers(self) -> list[str]:
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, check=False).stdout.decode()
        return [line.split()[0] for line in listed.splitlines() if line.startswith(self.tag)]
