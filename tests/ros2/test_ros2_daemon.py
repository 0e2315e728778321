"""mrosd with ``[ros2] enabled``: an mrosd node's /chatter reaches a zenoh-ros2-sdk subscriber."""

from __future__ import annotations

import asyncio
import queue
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class
from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import Processes

pytest.importorskip("zenoh")
pytest.importorskip("zenoh_ros2_sdk")
String = get_message_class("std_msgs/String")


async def test_the_daemons_ros2_part_serves_a_ros2_subscriber(
    procs: Processes, tmp_path: Path, router: int, messages_dir: Path
) -> None:
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.session import ZenohSession

    cfg = tmp_path / "mrosd.toml"
    cfg.write_text(
        "[ixm]\nenabled = false\n[rosout]\nenabled = false\n"
        f'[ros2]\nenabled = true\ndomain_id = 0\nconnect = ["tcp/127.0.0.1:{router}"]\nto_ros2 = ["/chatter"]\n'
    )
    (tmp_path / "d").mkdir()
    daemon = DaemonRun(procs, tmp_path / "d", "--config", str(cfg))
    got: queue.Queue[Any] = queue.Queue(maxsize=100)
    sub = ROS2Subscriber(
        topic="/chatter",
        msg_type="std_msgs/msg/String",
        callback=lambda msg: got.put_nowait(msg.data) if not got.full() else None,
        domain_id=0,
        router_ip="127.0.0.1",
        router_port=router,
    )
    try:
        await asyncio.to_thread(daemon.ready)
        async with mrosd.Node("talker", master_uri=daemon.uri, argv=[], host="127.0.0.1") as node:
            pub = await node.advertise("/chatter", String)
            async with backports.timeout(30):
                while True:
                    msg = String()
                    msg.data = "hello from mrosd"
                    await pub.publish(msg)
                    try:
                        data = await asyncio.to_thread(got.get, True, 0.2)
                    except queue.Empty:
                        continue
                    break
            assert data == "hello from mrosd"
    finally:
        await asyncio.to_thread(daemon.stop)
        daemon.notify.close()
        sub.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()
