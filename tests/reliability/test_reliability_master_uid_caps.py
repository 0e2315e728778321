"""Another uid floods the master from 127.0.0.1: the robot's own nodes (same address, other uids) keep working.

Every local node connects from a loopback address, so a cap per address made one flooding uid lock out all of
them (issue 24: 2048 idle connections from another uid, then 0 of 9 registrations and lookups answered;
rosmaster, one thread per connection, answered 9 of 9). The master now counts local connections by the uid
owning the peer's socket (the kernel's socket table, looked up only when a cap is near) and sheds the
flooder's oldest idle connection rather than refusing another uid's. Needs root (to create the second user);
skipped otherwise.
"""

from __future__ import annotations

import os
import pwd
import socket
import subprocess
import time
import xmlrpc.client
from typing import Any, cast

import pytest

from tests.reliability.test_reliability_master_http import MasterProcess
from tests.rosenv import Processes

FLOOD_USER = "trustmaster-flood"

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="creating a second uid to flood from needs root")

#: Opens argv[2] idle connections to 127.0.0.1:argv[1] as the uid it runs under, reopening any the master
#: closes (as a persistent attacker would); prints "open N" once all were opened, then keeps them.
FLOODER = r"""
import resource, selectors, socket, sys, time
port, count = int(sys.argv[1]), int(sys.argv[2])
_, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
sel = selectors.DefaultSelector()
def dial():
    try:
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
    except OSError:
        return False
    s.setblocking(False)
    sel.register(s, selectors.EVENT_READ)
    return True
opened = sum(dial() for _ in range(count))
print("open", opened, flush=True)
while True:
    for key, _ in sel.select(0.2):
        sock = key.fileobj
        try:
            data = sock.recv(4096)
        except OSError:
            data = b""
        if not data:
            sel.unregister(sock)
            sock.close()
            dial()
"""


def flood_uid() -> int:
    try:
        return pwd.getpwnam(FLOOD_USER).pw_uid
    except KeyError:
        subprocess.run(["useradd", "-r", "-M", "-s", "/usr/sbin/nologin", FLOOD_USER], check=True)
        return pwd.getpwnam(FLOOD_USER).pw_uid


def start_flooder(procs: Processes, port: int, count: int) -> subprocess.Popen[bytes]:
    uid = flood_uid()
    proc = subprocess.Popen(
        ["/usr/bin/python3", "-c", FLOODER, str(port), str(count)],  # stdlib only; /root is closed to the user
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        user=uid,
        group=uid,
        extra_groups=[],
        start_new_session=True,
    )
    procs._procs.append(proc)
    assert proc.stdout is not None
    line = proc.stdout.readline().decode()
    assert line.startswith("open "), line
    return proc


def timed_call(uri: str, method: str, *args: Any) -> tuple[float, Any]:
    """One call over a fresh connection, as rospy's ServerProxy makes them; (seconds, reply or the error)."""
    start = time.monotonic()
    try:
        with xmlrpc.client.ServerProxy(uri) as proxy:
            reply: Any = getattr(proxy, method)(*args)
    except (OSError, xmlrpc.client.Error) as exc:
        reply = exc
    return time.monotonic() - start, reply


NODE_CALLS: list[tuple[str, tuple[Any, ...]]] = [
    ("registerPublisher", ("/talker", "/chatter", "std_msgs/String", "http://127.0.0.1:1/")),
    ("registerSubscriber", ("/listener", "/chatter", "std_msgs/String", "http://127.0.0.1:2/")),
    ("lookupNode", ("/listener", "/talker")),
    ("setParam", ("/talker", "/rate", 10)),
    ("getParam", ("/talker", "/rate")),
    ("registerService", ("/talker", "/srv", "rosrpc://127.0.0.1:3", "http://127.0.0.1:1/")),
    ("lookupService", ("/listener", "/srv")),
    ("getSystemState", ("/listener",)),
    ("getTopicTypes", ("/listener",)),
]


def assert_local_nodes_served(master: MasterProcess) -> list[float]:
    """The 9 calls of two local nodes each answered with code 1 within 1 s, getPid within 100 ms."""
    times = []
    for method, args in NODE_CALLS:
        elapsed, reply = timed_call(master.uri, method, *args)
        assert isinstance(reply, list) and reply[0] == 1, f"{method}: {reply!r}"
        assert elapsed < 1.0, f"{method} took {elapsed:.3f} s"
        times.append(elapsed)
        elapsed, reply = timed_call(master.uri, "getPid", "/probe")
        assert cast(list[Any], reply)[2] == master.proc.pid, reply
        assert elapsed < 0.1, f"getPid took {elapsed * 1000:.0f} ms"
        times.append(elapsed)
    return times


def fd_count(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
def test_a_uid_flooding_from_loopback_does_not_lock_out_other_local_uids(procs: Processes, loop: str) -> None:
    """The issue's attack at the default caps: 2048 + 200 idle connections from another uid."""
    master = MasterProcess(procs, nofile=16384, loop=loop)
    start_flooder(procs, master.port, 2048 + 200)
    times = assert_local_nodes_served(master)
    fds = fd_count(master.proc.pid)
    print(f"18 calls during the flood (ms): {[round(t * 1000, 1) for t in times]}; master fds {fds}")
    assert fd_count(master.proc.pid) < 2048 + 100  # the flooder got its share, not more


def test_at_the_global_cap_the_flooders_oldest_idle_connection_gives_way(procs: Processes) -> None:
    master = MasterProcess(procs, kwargs={"max_connections": 120, "max_connections_per_host": 100})
    flooder = start_flooder(procs, master.port, 100)
    filler = [socket.create_connection(("127.0.0.1", master.port)) for _ in range(20)]  # root: 120 in all
    try:
        time.sleep(0.2)
        times = assert_local_nodes_served(master)
        print(f"at the global cap: 18 calls, slowest {max(times) * 1000:.1f} ms")
        assert flooder.poll() is None
    finally:
        for s in filler:
            s.close()
