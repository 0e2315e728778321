"""The Zenoh link of the ros2 part cut and restored (root only): an mrosd daemon with ``[ros2]`` and a rospy
talker in one namespace, a Zenoh router (as ``rmw_zenohd``) and a zenoh-ros2-sdk subscriber in another.

The daemon's link is cut (``ip link set down``) for 10 s, past Zenoh's 10 s lease, and restored: data reaches the
ROS 2 subscriber again within a bounded time, with no action from anyone; meanwhile the master and the bridge's
own ROS 1 node answer ``getPid`` as fast as ever (a dead link never stalls the ROS 1 side).
"""

from __future__ import annotations

import os
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.fleet.test_fleet_netns import Arrivals
from tests.netns.nsutil import MASTER_PORT, ZENOH_PORT, NetnsLab, lab_daemon_config
from tests.netns.test_netns_ros import TALKER
from tests.rosenv import ROS_PYTHON, Processes, needs_ros, ros_env

pytest.importorskip("zenoh", reason="the ros2 tests need eclipse-zenoh (pip install 'mrosd[ros2]')")
pytest.importorskip("zenoh_ros2_sdk")
pytestmark = [pytest.mark.root, pytest.mark.interop, needs_ros]

MASTER = f"http://127.0.0.1:{MASTER_PORT}/"
CUT_SECONDS = 10.0
#: Zenoh's peer reconnects with a backoff after its lease expired; rmw_zenoh's nodes see the same
RESUME_BOUND = 10.0

#: the ROS 2 machine: the router rmw_zenoh's nodes use, and a zenoh-ros2-sdk subscriber printing each message
ROS2_SIDE = textwrap.dedent(
    f"""
    import sys, time, zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", '["tcp/0.0.0.0:{ZENOH_PORT}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    router = zenoh.open(conf)
    from zenoh_ros2_sdk import ROS2Subscriber, message_registry
    message_registry._registry = message_registry.MessageRegistry(sys.argv[1])
    def heard(msg):
        sys.stdout.write(msg.data + "\\n")
        sys.stdout.flush()
    sub = ROS2Subscriber(topic="/chatter", msg_type="std_msgs/msg/String", callback=heard, domain_id=0,
                         router_ip="127.0.0.1", router_port={ZENOH_PORT})
    print("ready", flush=True)
    while True:
        time.sleep(1)
    """
)

#: getPid on the master and on the bridge's node every 0.05 s for argv[2] s; prints the slowest of each (s)
GETPID_PROBE = textwrap.dedent(
    """
    import socket, sys, time, xmlrpc.client
    socket.setdefaulttimeout(10)
    master, seconds = sys.argv[1], float(sys.argv[2])
    with xmlrpc.client.ServerProxy(master) as m:
        node = m.lookupNode("/probe", "/mrosd_ros2")[2]
    slowest, stop = [0.0, 0.0], time.monotonic() + seconds
    while time.monotonic() < stop:
        for i, uri in enumerate((master, node)):
            t0 = time.monotonic()
            with xmlrpc.client.ServerProxy(uri) as p:
                p.getPid("/probe")
            slowest[i] = max(slowest[i], time.monotonic() - t0)
        time.sleep(0.05)
    print(slowest[0], slowest[1])
    """
)


def test_the_zenoh_link_cut_for_10s_then_data_resumes_and_ros1_never_stalls(
    netns_lab: NetnsLab, procs: Processes, tmp_path: Path
) -> None:
    lab = netns_lab
    ros2_section = f"""
    [ros2]
    enabled = true
    domain_id = 0
    connect = ["tcp/{lab.addrs[1]}:{ZENOH_PORT}"]
    to_ros2 = ["/chatter"]
    """
    cfg = lab_daemon_config(tmp_path / "robot.toml", textwrap.dedent(ros2_section))
    messages = tmp_path / "messages" / "std_msgs" / "msg"
    messages.mkdir(parents=True)
    (messages / "String.msg").write_text("string data\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_"))}
    env["PYTHONPATH"] = os.pathsep.join([str(Path.cwd()), str(Path.cwd() / "cli")])
    ros2 = procs.start(lab.argv(1, [sys.executable, "-c", ROS2_SIDE, str(tmp_path / "messages")]), env)
    arrivals = Arrivals(ros2)
    ready = arrivals.wait_after(0.0, 30)  # the router listens before the daemon dials it
    with open(tmp_path / "daemon.log", "wb") as log:
        procs.start(lab.argv(0, [sys.executable, "-m", "mrosd.daemon", "--config", str(cfg)]), env, stderr=log.fileno())
    lab.exec_ok(
        lab.hosts[0],
        [sys.executable, "-c", f"from tests.rosenv import wait_for_xmlrpc; wait_for_xmlrpc({MASTER!r}, 30)"],
        timeout=40,
    )
    procs.start(lab.argv(0, [ROS_PYTHON, "-c", TALKER]), ros_env(MASTER, tmp_path / "h1"))
    try:
        arrivals.wait_after(ready, 40)
    except TimeoutError:
        ros2.kill()
        print((tmp_path / "daemon.log").read_text()[-3000:], ros2.stderr.read().decode()[-3000:] if ros2.stderr else "")
        raise

    probe = procs.start(lab.argv(0, [sys.executable, "-c", GETPID_PROBE, MASTER, str(CUT_SECONDS + 3)]), env)
    link = f"{lab.tag}i1"[-15:]
    lab.exec_ok(lab.hosts[0], ["ip", "link", "set", link, "down"])
    cut = time.monotonic()
    time.sleep(CUT_SECONDS)  # the cut itself is what is measured: nothing to wait on
    lab.exec_ok(lab.hosts[0], ["ip", "link", "set", link, "up"])
    restored = time.monotonic()
    assert not [t for t in arrivals.times if cut + 0.5 < t < restored], "data crossed a cut link"
    resumed = arrivals.wait_after(restored, 30)
    out, _ = probe.communicate(timeout=30)
    slowest_master, slowest_node = (float(x) for x in out.decode().split())
    print(
        f"ROS 2 data resumed {resumed - restored:.2f} s after the link came back; slowest getPid during the cut: "
        f"master {slowest_master * 1000:.1f} ms, bridge node {slowest_node * 1000:.1f} ms"
    )
    assert resumed - restored <= RESUME_BOUND
    assert max(slowest_master, slowest_node) < 1.0, "the ROS 1 side was slowed by the cut"
