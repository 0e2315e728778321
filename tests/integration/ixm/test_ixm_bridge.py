"""IXM <-> ROS topic bridges against real ROS: rospy sees each key write, rostopic pub feeds a key."""

from __future__ import annotations

import asyncio
import os
import subprocess
import textwrap
from pathlib import Path

import pytest

from mrosd import backports
from mrosd.errors import ConfigError
from mrosd.ixm import AsyncIxmClient
from mrosd.ixm.bridge import Bridge, IxmBridge, parse_bridges
from mrosd.ixm.server import IxmServer
from tests.integration.ixm.conftest import ShmGuard
from tests.rosenv import Processes, needs_ros, ros_env


def test_bridges_are_parsed_from_the_rules_table_with_clear_errors() -> None:
    raw = {
        "bridges": {
            "/v": {"type": "std_msgs/Float64"},
            "/w": {"type": "std_msgs/String", "topic": "/t", "direction": "from_topic", "max_size": 64},
        }
    }
    assert parse_bridges(raw) == [
        Bridge(key="/v", topic="/v", type="std_msgs/Float64", direction="to_topic"),
        Bridge(key="/w", topic="/t", type="std_msgs/String", direction="from_topic", max_size=64),
    ]
    with pytest.raises(ConfigError, match="direction"):
        parse_bridges({"bridges": {"/v": {"type": "std_msgs/Float64", "direction": "both"}}})
    with pytest.raises(ConfigError, match="message type"):
        parse_bridges({"bridges": {"/v": {"type": "float64"}}})


class Lines:
    """Lines of a child's stdout read on the event loop (no thread that could outlive the test)."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdout is not None
        self.fd = proc.stdout.fileno()
        os.set_blocking(self.fd, False)
        self.buf = b""
        self.seen: list[str] = []

    async def expect(self, expected: str, timeout: float = 20.0) -> None:
        loop = asyncio.get_running_loop()
        async with backports.timeout(timeout):
            while True:
                while b"\n" in self.buf:
                    line, self.buf = self.buf.split(b"\n", 1)
                    self.seen.append(line.decode().strip())
                    if self.seen[-1] == expected:
                        return
                ready = loop.create_future()
                loop.add_reader(self.fd, lambda f=ready: f.done() or f.set_result(None))
                try:
                    await ready
                finally:
                    loop.remove_reader(self.fd)
                chunk = os.read(self.fd, 4096)
                assert chunk, f"process ended before {expected!r}; it printed {self.seen}"
                self.buf += chunk


@needs_ros
async def test_rospy_sees_each_write_and_rostopic_pub_feeds_a_key(
    shm_guard: ShmGuard, rosmaster: str, procs: Processes, tmp_path: Path
) -> None:
    sock = str(tmp_path / "ixm.sock")
    env = ros_env(rosmaster, tmp_path)
    bridges = [
        Bridge(key="/ixm/out", topic="/ixm_out", type="std_msgs/Float64", direction="to_topic"),
        Bridge(key="/ixm/in", topic="/ixm_in", type="std_msgs/Float64", direction="from_topic"),
    ]
    listener = procs.python(
        textwrap.dedent(
            """
            import rospy
            from std_msgs.msg import Float64
            rospy.init_node("ixm_listener")
            rospy.Subscriber("/ixm_out", Float64, lambda m: print("got", m.data, flush=True))
            while rospy.get_published_topics() is not None and not rospy.is_shutdown():
                if any(t == "/ixm_out" for t, _ in rospy.get_published_topics()):
                    break
                rospy.sleep(0.05)
            print("ready", flush=True)
            rospy.spin()
            """
        ),
        env,
    )
    from mrosd.msg import get_message_class

    Float64 = get_message_class("std_msgs/Float64")
    lines = Lines(listener)
    async with IxmServer(sock), IxmBridge(sock, rosmaster, bridges), AsyncIxmClient(sock) as ixm:
        out = await ixm.open("/ixm/out", "std_msgs/Float64", mode="w")
        await lines.expect("ready")
        # the subscriber's TCPROS connection may still be forming: write until rospy reports a value
        async with backports.timeout(20):
            value = 1.0
            while True:
                out.write(Float64(data=value))
                try:
                    await lines.expect(f"got {value}", timeout=1.0)
                    break
                except TimeoutError:
                    value += 1.0
        out.write(Float64(data=42.5))
        await lines.expect("got 42.5")

        key_in = await ixm.open("/ixm/in", "std_msgs/Float64", mode="r")
        procs.start(["rostopic", "pub", "-r", "20", "/ixm_in", "std_msgs/Float64", "data: 7.25"], env)
        assert (await key_in.wait(timeout=20)).data == 7.25
