"""A stranger's Zenoh peer against what the fleet part holds for it: bytes, not only counts.

The robot imports ``/evil/**`` and a rospy node subscribes to four names there; a bare Zenoh session in another
process (so that its own buffers are not counted here) announces those topics and floods them with 8 MiB
bodies, as fast as the link takes them. What the bridge holds for them follows a byte budget, never the peer's
sends: this process's peak RSS (the master and the bridge) grows by less than the bar of issue 31 (256 MiB), the
master answers ``getPid`` within a second throughout, and the drops are a few log lines. Before, each topic
held ``queue_size`` (16) bodies whatever their size, behind zenoh-python's own queue, which has no bound.
"""

from __future__ import annotations

import asyncio
import logging
import subprocess
from pathlib import Path

import pytest

from mrosd.fleet.keys import ItemKind, data_key, discovery_key
from mrosd.msg import get_message_class
from tests.reliability.test_reliability_fleet_trust import default_robot
from tests.reliability.test_reliability_ros2_bytes import RSS_BAR, MiB, _Pinger, _reset_peak, _rss
from tests.rosenv import ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

zenoh = pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")

String = get_message_class("std_msgs/String")
TOPICS = [f"/chatter{i}" for i in range(4)]

LISTENER = """
import sys, rospy
from std_msgs.msg import String
rospy.init_node("listener")
for name in sys.argv[1:]:
    rospy.Subscriber(name, String, lambda m: None)
print("ready"); sys.stdout.flush()
rospy.spin()
"""

#: a peer in its own process: announces the data keys on its command line (every second, as a bridge does),
#: says "ready", waits for "go", puts ``rounds`` bodies of ``size`` bytes on each key, says "done"
FLOODER = """
import sys, struct, threading, time, zenoh
endpoint, rounds, size, *pairs = sys.argv[1:]
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
announcements, keys = pairs[0::2], pairs[1::2]
def announce():
    while True:
        for a in announcements:
            session.put(a, b"")
        time.sleep(0.5)
threading.Thread(target=announce, daemon=True).start()
publishers = [session.declare_publisher(k) for k in keys]
print("ready", flush=True)
sys.stdin.readline()
text = b"x" * (int(size) - 4)
body = struct.pack("<I", len(text)) + text
for _ in range(int(rounds)):
    for pub in publishers:
        pub.put(body)
print("done", flush=True)
sys.stdin.readline()
"""


@needs_ros
async def test_a_peer_flooding_big_bodies_into_imported_topics_holds_a_byte_budget_not_its_sends(
    procs: Processes, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, logger="mrosd"):
        async with default_robot(receive_topics=["/evil/**"]) as (master, bridge, endpoint):
            names = [f"/evil{t}" for t in TOPICS]
            listener = procs.start([ROS_PYTHON, "-c", LISTENER, *names], ros_env(master.uri, tmp_path))
            assert await asyncio.to_thread(lambda: list(iter_lines_until(listener, 1, 30))) == ["ready"]
            pairs = []
            for t in TOPICS:
                pairs.append(discovery_key(ItemKind.PUBLISHER, String._type, String._md5sum, "evil", t))
                pairs.append(data_key(String._type, String._md5sum, "evil", t))
            flooder = procs.our_python(["-c", FLOODER, endpoint, "32", str(8 * MiB), *pairs], stdin=subprocess.PIPE)
            assert await asyncio.to_thread(lambda: list(iter_lines_until(flooder, 1, 30))) == ["ready"]
            # the bridge subscribes in Zenoh once the local subscriber is connected to its publisher
            await bridge.wait_until(
                lambda: all(
                    (rt := bridge.received.get(f"/evil{t}")) is not None and rt.subscriber is not None for t in TOPICS
                ),
                30,
            )
            _reset_peak()
            base = _rss("VmRSS")
            pinger = _Pinger(master.uri)
            ping = asyncio.create_task(asyncio.to_thread(pinger.run))
            try:
                assert flooder.stdin is not None
                flooder.stdin.write(b"go\n")
                flooder.stdin.flush()
                assert await asyncio.to_thread(lambda: list(iter_lines_until(flooder, 1, 90))) == ["done"]
                await asyncio.sleep(1.0)  # what is still on its way is received, published or dropped
            finally:
                pinger.stop = True
                await ping
            growth = _rss("VmHWM") - base
            received = bridge.status()["received"]
            print(f"peak RSS growth {growth / MiB:.0f} MiB; getPid worst {pinger.worst * 1000:.0f} ms; {received}")
            assert any(r["messages"] for r in received.values()), "nothing was received: the flood never arrived"
            assert growth < RSS_BAR, f"peak RSS grew by {growth / MiB:.0f} MiB"
            assert pinger.worst < 1.0
            flooder.stdin.write(b"bye\n")
            flooder.stdin.flush()
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
    assert len([r for r in caplog.records if r.levelno >= logging.WARNING]) <= 10
