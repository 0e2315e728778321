"""roslibpy's and roslibjs's ``TFClient`` against the daemon, with no tf2_web_republisher node running.

One ``mrosd`` daemon (its web part answers tf2_web_republisher's service and action), one Debian tf2_ros
broadcaster (rospy, /usr/bin/python3): ``world -> base`` static, ``base -> arm`` moving (message k: x = 0.001 k,
a rotation of 0.01 k rad about z). Every transform a client receives must be ``world <- arm`` for one k, to 1e-6.
"""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.actions import Status
from mrosd.msg import get_message_class
from tests.rosenv import ROS_PYTHON, Processes, iter_lines_until, ros_available, ros_env
from tests.web.roslib_tf_browser import Browser, needs_chromium, page_server
from tests.web.webdaemon import WebDaemon

pytestmark = pytest.mark.skipif(not ros_available(), reason="needs Debian's rospy and tf2_ros (/usr/bin/python3)")

BROADCASTER = """
import math, rospy, tf2_ros
from geometry_msgs.msg import TransformStamped
rospy.init_node("mover")
static = tf2_ros.StaticTransformBroadcaster()
moving = tf2_ros.TransformBroadcaster()
s = TransformStamped()
s.header.stamp = rospy.Time.now()
s.header.frame_id, s.child_frame_id = "world", "base"
s.transform.translation.x, s.transform.translation.y = 1.0, 2.0
s.transform.rotation.w = 1.0
static.sendTransform(s)
k = 0
rate = rospy.Rate(50)
while not rospy.is_shutdown():
    k += 1
    t = TransformStamped()
    t.header.stamp = rospy.Time.now()
    t.header.frame_id, t.child_frame_id = "base", "arm"
    t.transform.translation.x, t.transform.translation.z = 0.001 * k, 0.5
    t.transform.rotation.z, t.transform.rotation.w = math.sin(0.005 * k), math.cos(0.005 * k)
    moving.sendTransform(t)
    rate.sleep()
"""

ROSLIBPY = """
import json, sys, time, roslibpy
from roslibpy.tf import TFClient
ros = roslibpy.Ros(host="127.0.0.1", port=int(sys.argv[1]))
ros.run()
tf = TFClient(ros, fixed_frame="/world", angular_threshold=0.001, translation_threshold=0.001, rate=20.0)
tf.subscribe("arm", lambda t: print(json.dumps(t), flush=True))
time.sleep(60)
"""


def step_of(translation: list[float], rotation: list[float]) -> int:
    """The broadcaster's k that gives ``world <- arm`` = (translation, rotation), checked to 1e-6."""
    k = round((translation[0] - 1.0) / 0.001)
    assert k >= 1
    expected = [1.0 + 0.001 * k, 2.0, 0.5], [0.0, 0.0, math.sin(0.005 * k), math.cos(0.005 * k)]
    for got, want in zip([*translation, *rotation], [*expected[0], *expected[1]], strict=True):
        assert abs(got - want) < 1e-6, (translation, rotation, k)
    return k


Robot = tuple[Processes, WebDaemon, str]


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    """The daemon (allowing the page's origin), the broadcaster, and the page's origin."""
    tmp = tmp_path_factory.mktemp("tf_clients")
    procs = Processes(tmp)
    try:
        origin = page_server(procs)
        daemon = WebDaemon(procs, tmp, MROSD_WEB_ALLOWED_ORIGINS=origin)
        procs.start([ROS_PYTHON, "-c", BROADCASTER], ros_env(daemon.uri, tmp), stdout=subprocess.DEVNULL)
        yield procs, daemon, origin
        daemon.close()
    finally:
        procs.close()


async def goal_statuses(master_uri: str) -> list[Status]:
    """The statuses in /tf2_web_republisher/status (a finished goal stays listed for 5 s)."""
    async with mrosd.Node("status_reader", master_uri=master_uri, argv=[], host="127.0.0.1") as node:
        sub = await node.subscribe("/tf2_web_republisher/status", get_message_class("actionlib_msgs/GoalStatusArray"))
        async with backports.timeout(10):
            async for msg in sub:
                return [Status(s.status) for s in msg.status_list]
    raise AssertionError("no status")


def no_republisher_node_but_mrosds(daemon: WebDaemon) -> None:
    import xmlrpc.client

    with xmlrpc.client.ServerProxy(daemon.uri) as master:
        code, _, _ = master.lookupService("/test", "/republish_tfs")
        assert code == 1
        code, _, node_uri = master.lookupNode("/test", "/tf2_web_republisher")
    assert code == 1 and node_uri  # the daemon's own node of that name: nothing else runs
    assert not Path("/opt/ros").joinpath("noetic/lib/tf2_web_republisher").exists()


def test_roslibpys_tfclient_receives_the_moving_frame_from_the_daemon(robot: Robot) -> None:
    procs, daemon, _ = robot
    client = procs.start([sys.executable, "-c", ROSLIBPY, str(daemon.rosbridge_port)], stderr=subprocess.DEVNULL)
    steps = [
        step_of([t["translation"][a] for a in "xyz"], [t["rotation"][a] for a in "xyzw"])
        for t in (json.loads(line) for line in iter_lines_until(client, 4, 30.0))
    ]
    assert steps == sorted(steps) and steps[-1] > steps[0]  # it moves, and only forward
    no_republisher_node_but_mrosds(daemon)  # it joined the graph with the first web client
    procs.stop(client)


@needs_chromium
def test_roslibjs_tfclient_in_chromium_receives_the_moving_frame_and_cancels_its_goal(
    robot: Robot,
) -> None:
    procs, daemon, origin = robot
    browser = Browser(procs, origin, daemon.rosbridge_url)
    try:
        params: dict[str, Any] = {"fixed": "world", "angular": 0.001, "trans": 0.001, "rate": 20}
        browser.send(cmd="tf_subscribe", frame="arm", **params)
        steps = [step_of(ev["translation"], ev["rotation"]) for ev in (browser.until("tf") for _ in range(4))]
        assert steps == sorted(steps) and steps[-1] > steps[0]
        # a second frame: roslibjs cancels its goal and sends one for both; the static frame arrives once
        browser.send(cmd="tf_subscribe", frame="base", **params)
        base = browser.until("tf", frame="base")
        assert base["translation"] == [1.0, 2.0, 0.0] and base["rotation"] == [0.0, 0.0, 0.0, 1.0]
        arm = browser.until("tf", frame="arm")
        step_of(arm["translation"], arm["rotation"])
        assert asyncio.run(goal_statuses(daemon.uri)) == [Status.PREEMPTED, Status.ACTIVE]
    finally:
        browser.close()
