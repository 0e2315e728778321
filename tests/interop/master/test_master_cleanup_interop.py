"""A graph that cleans itself: dead nodes (slave API refusing connections) are removed, live ones never.

Socket-level tests drive ``GraphCleaner.sweep`` directly against real listening, refusing and
stopped sockets; the interop tests kill or stop a real rospy node under our master and look with
the real ``rosnode list``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
import xmlrpc.client
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from mrosd.master.cleanup import GraphCleaner, Probe
from mrosd.master.registry import Notification, Registry
from tests.interop.master.conftest import RecordingSlave
from tests.rosenv import Processes, free_port, iter_lines_until, needs_ros, ros_env


def refusing_uri() -> str:
    """The URI of a port nothing listens on (bound, then closed)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{s.getsockname()[1]}/"


@pytest.fixture
def silent_listener() -> Iterator[str]:
    """A socket that listens but never accepts or answers, like a node stopped with SIGSTOP."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        yield f"http://127.0.0.1:{s.getsockname()[1]}/"


def cleaner(registry: Registry, sent: list[Notification]) -> GraphCleaner:
    return GraphCleaner(registry, sent.extend, interval=0.4)


async def test_a_node_whose_slave_api_refuses_connections_is_removed_and_subscribers_told(
    make_slave: Callable[[], RecordingSlave],
) -> None:
    listener = make_slave()
    dead = refusing_uri()
    r = Registry()
    r.register_subscriber("/listener", "/t", "std_msgs/String", listener.uri)
    r.register_publisher("/dead", "/t", "std_msgs/String", dead)
    r.register_service("/dead", "/srv", "rosrpc://127.0.0.1:1/", dead)
    sent: list[Notification] = []
    assert await cleaner(r, sent).sweep() == ["/dead"]
    assert r.lookup_node("/dead") is None and r.lookup_service("/srv") is None
    assert [(n.api, n.method, n.args) for n in sent] == [(listener.uri, "publisherUpdate", ("/t", []))]
    assert r.lookup_node("/listener") == listener.uri  # it answers: kept


async def test_a_node_that_answers_or_does_not_answer_at_all_is_never_removed(
    make_slave: Callable[[], RecordingSlave], silent_listener: str
) -> None:
    alive = make_slave()
    r = Registry()
    r.register_publisher("/alive", "/a", "std_msgs/String", alive.uri)
    r.register_publisher("/stopped", "/b", "std_msgs/String", silent_listener)
    sent: list[Notification] = []
    c = cleaner(r, sent)
    for _ in range(3):
        assert await c.sweep() == []
    assert c.pids == {alive.uri: 4242}  # learned once, for the pid check of a later refusal
    assert [m for m, _ in alive.calls] == ["getPid"]
    assert sorted(r.nodes) == ["/alive", "/stopped"] and sent == []


async def test_a_node_that_registers_again_while_probed_is_kept() -> None:
    dead = refusing_uri()
    r = Registry()
    r.register_publisher("/n", "/t", "std_msgs/String", dead)
    c = cleaner(r, [])
    before = c._entries(dead)
    r.register_publisher("/n", "/t", "std_msgs/String", dead)  # proof of life after the probe began
    assert c._remove(dead, before, Probe.REFUSED, None) == []
    assert r.lookup_node("/n") == dead


# --- real rospy nodes and rosnode under our master ---------------------------------------------

LAUNCH_MASTER = textwrap.dedent(
    """
    import asyncio, logging, sys
    from mrosd.master import Master

    async def main():
        logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s", stream=sys.stdout)
        async with Master("127.0.0.1", int(sys.argv[1])) as master:
            master.api.cleanup_interval = float(sys.argv[2])
            print("ready", flush=True)
            await asyncio.Event().wait()

    asyncio.run(main())
    """
)

TALKER = textwrap.dedent(
    """
    import rospy
    from std_msgs.msg import String
    rospy.init_node("talker")
    pub = rospy.Publisher("chatter", String, queue_size=10)
    rospy.Service("talker_srv", __import__("std_srvs.srv", fromlist=["Empty"]).Empty, lambda req: [])
    print("up", flush=True)
    rospy.spin()
    """
)

INTERVAL = 1.0


def master_with_cleanup(procs: Processes, interval: float) -> tuple[str, subprocess.Popen[bytes]]:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    proc = procs.start([sys.executable, "-c", LAUNCH_MASTER, str(port), str(interval)], ros_env(uri, procs.tmp))
    assert list(iter_lines_until(proc, 1, timeout=20)) == ["ready"]
    return uri, proc


def nodes(uri: str) -> set[str]:
    with xmlrpc.client.ServerProxy(uri) as m:
        pubs, subs, srvs = m.getSystemState("/test")[2]
    return {n for _, ns in [*pubs, *subs, *srvs] for n in ns}


def wait_until(predicate: Callable[[], Any], timeout: float) -> float:
    """Seconds until ``predicate()`` held (polled every 20 ms); fails after ``timeout``."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout:
            raise TimeoutError("condition not reached")
        time.sleep(0.02)
    return time.monotonic() - start


def rosnode_list(uri: str, procs: Processes) -> list[str]:
    done = subprocess.run(
        ["rosnode", "list"], env=ros_env(uri, procs.tmp), capture_output=True, text=True, timeout=30, check=False
    )
    return done.stdout.split()


@needs_ros
def test_a_node_killed_with_sigkill_leaves_rosnode_list_within_the_interval(procs: Processes) -> None:
    uri, master = master_with_cleanup(procs, INTERVAL)
    talker = procs.python(TALKER, ros_env(uri, procs.tmp))
    assert list(iter_lines_until(talker, 1, timeout=30)) == ["up"]
    wait_until(lambda: "/talker" in nodes(uri), 10)
    assert "/talker" in rosnode_list(uri, procs)
    os.killpg(talker.pid, signal.SIGKILL)
    talker.wait(10)
    # One sweep period plus the confirming getPid (loaded 2-core machine: allow 1 s of scheduling).
    elapsed = wait_until(lambda: "/talker" not in nodes(uri), INTERVAL + 1.0)
    assert elapsed <= INTERVAL + 1.0
    assert "/talker" not in rosnode_list(uri, procs)
    (line,) = iter_lines_until(master, 1, timeout=5)  # the one log line of the removal
    assert "removed dead node /talker" in line and "refuses connections" in line, line
    assert "(2 publications, 0 subscriptions, 3 services)" in line, line  # /chatter, /rosout; 2 logger services


@needs_ros
def test_a_node_stopped_with_sigstop_is_not_removed(procs: Processes) -> None:
    uri, _ = master_with_cleanup(procs, INTERVAL)
    talker = procs.python(TALKER, ros_env(uri, procs.tmp))
    assert list(iter_lines_until(talker, 1, timeout=30)) == ["up"]
    wait_until(lambda: "/talker" in nodes(uri), 10)
    os.killpg(talker.pid, signal.SIGSTOP)
    try:
        deadline = time.monotonic() + 4 * INTERVAL  # four sweeps: absence of a removal needs time
        while time.monotonic() < deadline:
            assert "/talker" in nodes(uri)
            time.sleep(0.1)
        assert "/talker" in rosnode_list(uri, procs)
    finally:
        os.killpg(talker.pid, signal.SIGCONT)
