"""Master, publisher and subscriber on three hosts (network namespaces), with ROS_HOSTNAME / ROS_IP per host.

Real Debian ROS first (proves the fixture and the addressing), then mrosd's master and nodes as they land.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.netns.nsutil import MASTER_PORT, NetnsLab
from tests.rosenv import ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

pytestmark = pytest.mark.root


TALKER = textwrap.dedent(
    """
    import rospy
    from std_msgs.msg import String
    rospy.init_node("talker", disable_signals=True)
    pub = rospy.Publisher("/chatter", String, queue_size=10)
    rate = rospy.Rate(20)
    i = 0
    while not rospy.is_shutdown():
        pub.publish(String(data="hello %d" % i))
        i += 1
        rate.sleep()
    """
)


def host_env(lab: NetnsLab, host: int, tmp: Path, *, use_ip: bool = False) -> dict[str, str]:
    """Environment of a ROS process on ``host``: the master on host 0, its own address advertised."""
    env = ros_env(f"http://{lab.addrs[0]}:{MASTER_PORT}/", tmp / f"h{host}")
    env.pop("ROS_HOSTNAME")
    env["ROS_IP" if use_ip else "ROS_HOSTNAME"] = lab.addrs[host]
    return env


def wait_for_xmlrpc_from(lab: NetnsLab, host: int, uri: str, timeout: float = 20.0) -> None:
    """Block until ``uri`` answers getPid when called from inside host namespace ``host``."""
    probe = textwrap.dedent(
        f"""
        import sys, time, xmlrpc.client
        deadline = time.monotonic() + {timeout}
        while time.monotonic() < deadline:
            try:
                with xmlrpc.client.ServerProxy({uri!r}) as p:
                    p.getPid("/probe")
                sys.exit(0)
            except Exception:
                time.sleep(0.05)
        sys.exit(1)
        """
    )
    done = subprocess.run(lab.argv(host, [sys.executable, "-c", probe]), timeout=timeout + 10, check=False)
    assert done.returncode == 0, f"{uri} did not answer from {lab.hosts[host]} within {timeout} s"


def lookup_node_from(lab: NetnsLab, host: int, node: str) -> str:
    code = (
        "import xmlrpc.client\n"
        f"with xmlrpc.client.ServerProxy('http://{lab.addrs[0]}:{MASTER_PORT}/') as p:\n"
        f"    print(p.lookupNode('/probe', {node!r})[2])\n"
    )
    return lab.exec_ok(lab.hosts[host], [sys.executable, "-c", code]).strip()


def echo_three(lab: NetnsLab, procs: Processes, tmp: Path, argv: list[str], env: dict[str, str]) -> list[str]:
    echo = procs.start(lab.argv(2, argv), env)
    lines = [line for line in iter_lines_until(echo, 6, timeout=30.0) if line.startswith("data:")]
    return lines


@needs_ros
def test_real_rosmaster_rospy_talker_and_rostopic_echo_talk_across_three_namespaces(
    netns_lab: NetnsLab, procs: Processes, tmp_path: Path
) -> None:
    lab = netns_lab
    master_env = host_env(lab, 0, tmp_path)
    procs.start(
        lab.argv(0, ["rosmaster", "--core", "-p", str(MASTER_PORT)]),
        master_env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc_from(lab, 1, f"http://{lab.addrs[0]}:{MASTER_PORT}/")

    procs.start(lab.argv(1, [ROS_PYTHON, "-c", TALKER]), host_env(lab, 1, tmp_path))
    echo_env = host_env(lab, 2, tmp_path, use_ip=True)
    lines = echo_three(lab, procs, tmp_path, ["rostopic", "echo", "-n", "3", "/chatter"], echo_env)

    assert len(lines) == 3 and all(line.startswith('data: "hello ') for line in lines), lines
    # each node advertised the address of its own host, as set by ROS_HOSTNAME / ROS_IP
    assert lookup_node_from(lab, 2, "/talker").startswith(f"http://{lab.addrs[1]}:")


def test_the_namespaces_are_removed_even_when_processes_still_run_inside(procs: Processes) -> None:
    from tests.netns.nsutil import netns_unavailable

    why = netns_unavailable()
    if why is not None:
        pytest.skip(why)
    lab = NetnsLab()
    try:
        lab.setup()
        procs.start(lab.argv(1, ["sleep", "300"]))
        # hosts see each other over the bridge, and the caller's namespace has no address of the lab's /24
        lab.exec_ok(lab.hosts[0], [sys.executable, "-c", _CONNECT.format(addr=lab.addrs[1])])
        routes = subprocess.run(["ip", "route", "get", lab.addrs[1]], capture_output=True, check=False).stdout
        assert f"src {lab.net}.".encode() not in routes
    finally:
        lab.teardown()
    assert lab.leftovers() == []
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and lab.tag.encode() in subprocess.check_output(["ip", "link"]):
        time.sleep(0.05)
    assert lab.tag.encode() not in subprocess.check_output(["ip", "link"])


# a TCP connect to a closed port answers RST: proves the path without needing ping
_CONNECT = (
    "import socket\n"
    "s = socket.socket(); s.settimeout(5)\n"
    "try:\n"
    "    s.connect(('{addr}', 9))\n"
    "except ConnectionRefusedError:\n"
    "    pass\n"
)


def start_our_master(lab: NetnsLab, procs: Processes, tmp: Path, *extra: str, host: str = "0.0.0.0") -> None:
    procs.start(
        lab.argv(0, [sys.executable, "-m", "mrosd.master", "--host", host, "--port", str(MASTER_PORT), *extra]),
        host_env(lab, 0, tmp),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


@needs_ros
def test_our_master_and_our_talker_serve_rostopic_echo_on_a_third_host(
    netns_lab: NetnsLab, procs: Processes, tmp_path: Path
) -> None:
    from tests.reliability.relnodes import TALKER as OUR_TALKER

    lab = netns_lab
    start_our_master(lab, procs, tmp_path)
    wait_for_xmlrpc_from(lab, 1, f"http://{lab.addrs[0]}:{MASTER_PORT}/")
    talker = procs.start(
        lab.argv(1, [sys.executable, "-c", OUR_TALKER, "/chatter", "20", "talker"]), host_env(lab, 1, tmp_path)
    )
    assert next(iter_lines_until(talker, 1, 30.0)) == "ready"
    lines = echo_three(
        lab, procs, tmp_path, ["rostopic", "echo", "-n", "3", "/chatter"], host_env(lab, 2, tmp_path, use_ip=True)
    )
    assert len(lines) == 3 and all(line.startswith('data: "') for line in lines), lines
    assert lookup_node_from(lab, 2, "/talker").startswith(f"http://{lab.addrs[1]}:")


@needs_ros
def test_a_rospy_talker_reaches_our_listener_on_another_host_through_our_master(
    netns_lab: NetnsLab, procs: Processes, tmp_path: Path
) -> None:
    from tests.reliability.relnodes import LISTENER as OUR_LISTENER

    lab = netns_lab
    start_our_master(lab, procs, tmp_path)
    wait_for_xmlrpc_from(lab, 1, f"http://{lab.addrs[0]}:{MASTER_PORT}/")
    procs.start(lab.argv(1, [ROS_PYTHON, "-c", TALKER]), host_env(lab, 1, tmp_path, use_ip=True))
    listener = procs.start(
        lab.argv(2, [sys.executable, "-c", OUR_LISTENER, "/chatter", "listener"]), host_env(lab, 2, tmp_path)
    )
    lines = list(iter_lines_until(listener, 3, timeout=30.0))
    assert all(line.startswith("hello ") for line in lines), lines
    assert lookup_node_from(lab, 1, "/listener").startswith(f"http://{lab.addrs[2]}:")


def test_the_master_allow_list_admits_the_listed_network_and_refuses_another_host(
    netns_lab: NetnsLab, procs: Processes, tmp_path: Path
) -> None:
    lab = netns_lab
    start_our_master(lab, procs, tmp_path, "--allow", f"{lab.addrs[1]}/32", "--allow", "127.0.0.0/8")
    uri = f"http://{lab.addrs[0]}:{MASTER_PORT}/"
    wait_for_xmlrpc_from(lab, 1, uri)  # host 2 is listed
    probe = (
        "import xmlrpc.client, sys\n"
        f"p = xmlrpc.client.ServerProxy({uri!r})\n"
        "try:\n"
        "    p.getPid('/intruder')\n"
        "except xmlrpc.client.ProtocolError as e:\n"
        "    print(e.errcode)\n"
        "    sys.exit(0)\n"
        "sys.exit(1)\n"
    )
    assert lab.exec_ok(lab.hosts[2], [sys.executable, "-c", probe]).strip() == "403"
    # the refusal did not disturb the master for the allowed host
    wait_for_xmlrpc_from(lab, 1, uri, timeout=5)


def test_a_master_bound_to_loopback_is_unreachable_from_other_hosts(
    netns_lab: NetnsLab, procs: Processes, tmp_path: Path
) -> None:
    lab = netns_lab
    start_our_master(lab, procs, tmp_path, host="127.0.0.1")
    wait_for_xmlrpc_from(lab, 0, f"http://127.0.0.1:{MASTER_PORT}/")  # up, on its own host
    probe = (
        "import socket\n"
        "s = socket.socket(); s.settimeout(5)\n"
        "try:\n"
        f"    s.connect(({lab.addrs[0]!r}, {MASTER_PORT}))\n"
        "    print('reached')\n"
        "except ConnectionRefusedError:\n"
        "    print('refused')\n"
    )
    assert lab.exec_ok(lab.hosts[1], [sys.executable, "-c", probe]).strip() == "refused"
