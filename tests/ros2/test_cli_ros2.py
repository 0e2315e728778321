"""``mros ros2 bridge`` against Debian's rosmaster: it announces its node to ROS 2 and stops on Ctrl-C."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mrosd import backports
from mrosd.ros2.keys import EntityKind, parse_token
from tests.ros2.test_ros2_interop import _tokens
from tests.rosenv import Processes, needs_ros

pytestmark = [needs_ros]
pytest.importorskip("zenoh")


def test_without_topics_it_is_a_usage_error() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "ros2", "bridge"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 2 and "--to-ros2" in done.stderr


async def test_mros_ros2_bridge_announces_its_node_and_stops_on_ctrl_c(
    procs: Processes, rosmaster: str, router: int, tmp_path: Path
) -> None:
    proc = procs.our_python(
        [
            "-m",
            "mros_cli.main",
            "--master-uri",
            rosmaster,
            "ros2",
            "bridge",
            "--to-ros2",
            "/chatter",
            "--connect",
            f"tcp/127.0.0.1:{router}",
            "--domain-id",
            "5",
        ]
    )
    async with backports.timeout(30):
        while not any(
            t.kind is EntityKind.NODE and t.node == "mrosd_ros2" and t.domain_id == 5
            for t in map(parse_token, await asyncio.to_thread(_tokens, router))
        ):
            assert proc.poll() is None, proc.communicate()
            await asyncio.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _out, err = await asyncio.to_thread(proc.communicate, None, 20)
    assert proc.returncode in (0, 130), err
    assert b"Traceback" not in err


async def test_mros_ros2_status_lists_the_bridged_topic(
    procs: Processes, rosmaster: str, router: int, tmp_path: Path
) -> None:
    import mrosd
    from mrosd.msg import get_message_class
    from mrosd.ros2.bridge import Ros2Bridge, Ros2Options

    String = get_message_class("std_msgs/String")
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=("/chatter",))
    async with (
        Ros2Bridge(options, rosmaster) as bridge,
        mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
    ):
        pub = await node.advertise("/chatter", String)
        msg = String()
        msg.data = "hi"

        def sent() -> bool:
            bt = bridge.topics.get("/chatter")
            return bt is not None and bt.rmw is not None and bt.rmw.sent > 0

        async with backports.timeout(30):
            while not sent():
                await pub.publish(msg)
                await asyncio.sleep(0.1)
        done = await asyncio.to_thread(
            subprocess.run,
            [sys.executable, "-m", "mros_cli.main", "--master-uri", rosmaster, "ros2", "status"],
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
    assert done.returncode == 0, done.stderr
    assert "/chatter  std_msgs/msg/String  " in done.stdout and " Hz  sent " in done.stdout


def test_mros_ros2_status_without_a_bridge_is_one_error_line(rosmaster: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", rosmaster, "ros2", "status"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 1 and "no ros2 bridge" in done.stderr and "Traceback" not in done.stderr
