"""``mros topic list --watch``: topics appear and vanish, pushed by mrosd and polled from rosmaster, same lines.

Registrations are made with a plain XML-RPC client standing in for nodes; the watcher is the real ``mros``
command line in a subprocess, read line by line within bounded waits.
"""

from __future__ import annotations

import json
import subprocess
import sys
import xmlrpc.client
from collections.abc import Iterator

import pytest

from tests.interop.master.conftest import RecordingSlave, start_our_master
from tests.interop.master.test_graph_watch import Lines
from tests.rosenv import Processes, needs_ros, ros_env, start_rosmaster

pytestmark = [needs_ros, pytest.mark.interop]

POLL = 0.1


@pytest.fixture(params=["rosmaster", "mrosd"])
def master(request: pytest.FixtureRequest, procs: Processes) -> str:
    return start_rosmaster(procs) if request.param == "rosmaster" else start_our_master(procs)


@pytest.fixture
def m(master: str) -> Iterator[xmlrpc.client.ServerProxy]:
    with xmlrpc.client.ServerProxy(master) as proxy:
        yield proxy


@pytest.fixture
def node_api() -> Iterator[str]:
    """A slave API that answers (our master's cleaner removes nodes whose port refuses connections)."""
    slave = RecordingSlave()
    try:
        yield slave.uri
    finally:
        slave.close()


def start_watch(procs: Processes, master: str, *extra: str) -> Lines:
    argv = [sys.executable, "-m", "mros_cli.main", "topic", "list", "--watch", "--poll", str(POLL), *extra]
    return Lines(procs.start(argv, ros_env(master, procs.tmp), stderr=None))


def test_topic_list_watch_shows_topics_appear_and_vanish(
    master: str, m: xmlrpc.client.ServerProxy, procs: Processes, node_api: str
) -> None:
    m.registerSubscriber("/listener", "/before", "std_msgs/String", node_api)
    watch = start_watch(procs, master)
    assert watch.take(1) == ["+ topic /before [std_msgs/String]"]  # the current topics first; no node lines
    m.registerPublisher("/talker", "/chatter", "std_msgs/String", node_api)
    assert watch.take(1) == ["+ topic /chatter [std_msgs/String]"]
    m.registerService("/talker", "/talker/srv", "rosrpc://127.0.0.1:9/", node_api)  # not a topic: not shown
    m.unregisterPublisher("/talker", "/chatter", node_api)
    assert watch.take(1) == ["- topic /chatter [std_msgs/String]"]
    m.unregisterSubscriber("/listener", "/before", node_api)
    assert watch.take(1) == ["- topic /before [std_msgs/String]"]
    assert watch.buf == b""


def test_topic_list_watch_namespace_and_json(
    master: str, m: xmlrpc.client.ServerProxy, procs: Processes, node_api: str
) -> None:
    watch = start_watch(procs, master, "--json", "/cam")
    m.registerPublisher("/other", "/camera", "std_msgs/Empty", node_api)  # /camera is not under /cam
    m.registerPublisher("/cam_node", "/cam/image", "sensor_msgs/Image", node_api)
    records = [json.loads(line) for line in watch.take(1)]
    m.unregisterPublisher("/cam_node", "/cam/image", node_api)
    records += [json.loads(line) for line in watch.take(1)]
    assert [(r["event"], r["kind"], r["name"], r["type"]) for r in records] == [
        ("appeared", "topic", "/cam/image", "sensor_msgs/Image"),
        ("vanished", "topic", "/cam/image", "sensor_msgs/Image"),
    ]


@pytest.mark.parametrize("args", [["-v"], ["-p"], ["-s"]])
def test_topic_list_watch_refuses_what_it_cannot_show(procs: Processes, args: list[str]) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "topic", "list", "--watch", *args],
        env=ros_env("http://127.0.0.1:9/", procs.tmp),
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 2 and "--watch lists every topic" in done.stderr, done.stderr
