"""The full daemon, web part on as shipped: a rospy publisher of a type the daemon cannot look up sees no
subscriber while no browser client is connected (issue 31, case 10), and one once a Foxglove client asks.

Real daemon, real rospy (Debian's ros_comm), a real Foxglove WebSocket client.
"""

from __future__ import annotations

import asyncio
import json
import re
from pathlib import Path

import aiohttp

from mrosd import backports
from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import Processes, iter_lines_until, needs_ros, ros_env

PUBLISHER = r"""
import sys, genpy.dynamic, rospy
Secret = genpy.dynamic.generate_dynamic("hubtest/Secret", "int32 x\nstring note\n")["hubtest/Secret"]

class Listener(rospy.SubscribeListener):
    def peer_subscribe(self, topic, num_peers, peer_publish):
        print("peer_subscribe", topic, flush=True)

    def peer_unsubscribe(self, topic, num_peers):
        print("peer_unsubscribe", topic, flush=True)

rospy.init_node("camera", disable_signals=True)
pub = rospy.Publisher("/secret", Secret, queue_size=1, subscriber_listener=Listener())
print("ready", flush=True)
rospy.spin()
"""


def foxglove_url(status: str) -> str:
    match = re.search(r"foxglove (ws://\S+/)", status)
    assert match, status
    return match.group(1)


async def advertised(url: str, topic: str, timeout: float = 15.0) -> dict[str, object]:
    async with (
        aiohttp.ClientSession() as http,
        http.ws_connect(url, protocols=["foxglove.websocket.v1"]) as ws,
        backports.timeout(timeout),
    ):
        while True:
            msg = json.loads((await ws.receive()).data)
            if msg["op"] == "advertise":
                for channel in msg["channels"]:
                    if channel["topic"] == topic:
                        return dict(channel)


@needs_ros
def test_a_rospy_publisher_sees_no_subscriber_until_a_browser_client_asks(procs: Processes, tmp_path: Path) -> None:
    run = DaemonRun(procs, tmp_path)
    try:
        url = foxglove_url(run.ready())
        camera = procs.python(PUBLISHER, ros_env(run.uri, tmp_path))
        assert list(iter_lines_until(camera, 1, 30.0)) == ["ready"]
        # Nobody asked for /secret: nothing may subscribe (the old hub did within half a second).
        try:
            seen = list(iter_lines_until(camera, 1, 2.0))
        except TimeoutError:  # no line in time: what we want
            seen = []
        assert seen == [], seen
        # A Foxglove client wants the channel list: now the hub learns the type from the publisher.
        channel = asyncio.run(advertised(url, "/secret"))
        assert channel["schemaName"] == "hubtest/Secret"
        assert str(channel["schema"]).startswith("int32 x")
        code, _ = run.stop()
        assert code == 0
    finally:
        run.close()
