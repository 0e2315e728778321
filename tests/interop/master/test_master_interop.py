"""Real Debian ROS tools and nodes (rostopic, rosparam, rosnode, rosservice, rospy, roscpp) against OUR master.

Our master runs as ``python -m mrosd.master`` in a subprocess on a free port; every ROS process gets
``ros_env`` pointing at it. Waits are on output lines with timeouts, never fixed sleeps.
"""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import textwrap
import time
from pathlib import Path

import pytest
import yaml

from mrosd.master import MasterClient
from tests.rosenv import Processes, free_port, iter_lines_until, needs_ros, ros_env, wait_for_xmlrpc

pytestmark = needs_ros


@pytest.fixture
def our_master(procs: Processes) -> str:
    """URI of our master started with ``python -m mrosd.master`` on a free port."""
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    env = ros_env(uri, procs.tmp)
    procs.our_python(["-m", "mrosd.master", "--port", str(port)], env, stdout=subprocess.DEVNULL)
    wait_for_xmlrpc(uri)
    return uri


def run(argv: list[str], env: dict[str, str], stdin: str | None = None, timeout: float = 30.0) -> str:
    """Run a ROS command line tool to completion and return its stdout (failing the test on error)."""
    done = subprocess.run(argv, env=env, input=stdin, capture_output=True, text=True, timeout=timeout, check=False)
    assert done.returncode == 0, f"{argv} failed ({done.returncode}): {done.stdout}\n{done.stderr}"
    return done.stdout


def wait_until(predicate: object, timeout: float = 15.0) -> None:
    """Poll a cheap condition (a master query) until it holds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return
        time.sleep(0.05)
    raise TimeoutError("condition not reached")


def graph_nodes(uri: str) -> set[str]:
    async def query() -> set[str]:
        async with MasterClient(uri, "/test") as c:
            pubs, subs, srvs = await c.get_system_state()
        return {n for _, nodes in [*pubs, *subs, *srvs] for n in nodes}

    return asyncio.run(query())


TALKER = textwrap.dedent(
    """
    import rospy
    from std_msgs.msg import String
    rospy.init_node("talker")
    pub = rospy.Publisher("chatter", String, queue_size=10)
    rate = rospy.Rate(20)
    i = 0
    while not rospy.is_shutdown():
        pub.publish(String(data="hello %d" % i)); i += 1
        rate.sleep()
    """
)

LISTENER = textwrap.dedent(
    """
    import rospy, sys
    from std_msgs.msg import String
    rospy.init_node("listener")
    rospy.Subscriber("chatter", String, lambda m: (sys.stdout.write(m.data + "\\n"), sys.stdout.flush()))
    rospy.spin()
    """
)


def test_rostopic_pub_and_echo_exchange_messages(our_master: str, procs: Processes) -> None:
    env = ros_env(our_master, procs.tmp)
    echo = procs.start(["rostopic", "echo", "/chatter"], env)
    procs.start(["rostopic", "pub", "-r", "10", "/chatter", "std_msgs/String", "data: hi there"], env)
    lines = list(iter_lines_until(echo, 2, timeout=20))
    assert lines == ['data: "hi there"', "---"]


def test_a_late_rostopic_echo_gets_the_latched_message(our_master: str, procs: Processes) -> None:
    env = ros_env(our_master, procs.tmp)
    procs.start(["rostopic", "pub", "-l", "/latched", "std_msgs/String", "data: kept"], env)

    def published() -> bool:
        async def q() -> bool:
            async with MasterClient(our_master, "/test") as c:
                return ("/latched", "std_msgs/String") in await c.get_published_topics()

        return asyncio.run(q())

    wait_until(published)
    out = run(["rostopic", "echo", "-n", "1", "/latched"], env, timeout=20)
    assert 'data: "kept"' in out


def test_rosparam_set_get_list_delete_dump_and_load(our_master: str, procs: Processes, tmp_path: Path) -> None:
    env = ros_env(our_master, procs.tmp)
    run(["rosparam", "set", "/robot", "{gains: {p: 1.5, i: 2}, name: r2}"], env)
    assert yaml.safe_load(run(["rosparam", "get", "/robot/gains"], env)) == {"p": 1.5, "i": 2}
    assert run(["rosparam", "get", "/robot/name"], env).strip() == "r2"
    assert set(run(["rosparam", "list"], env).split()) >= {"/robot/gains/p", "/robot/gains/i", "/robot/name"}
    dump = tmp_path / "dump.yaml"
    run(["rosparam", "dump", str(dump), "/robot"], env)
    assert yaml.safe_load(dump.read_text())["gains"] == {"p": 1.5, "i": 2}
    run(["rosparam", "delete", "/robot"], env)
    assert "/robot/name" not in run(["rosparam", "list"], env).split()
    run(["rosparam", "load", str(dump), "/copy"], env)
    assert yaml.safe_load(run(["rosparam", "get", "/copy"], env)) == {"gains": {"p": 1.5, "i": 2}, "name": "r2"}


def test_rospy_talker_and_listener_talk_through_our_master(our_master: str, procs: Processes) -> None:
    env = ros_env(our_master, procs.tmp)
    listener = procs.python(LISTENER, env)
    procs.python(TALKER, env)
    lines = list(iter_lines_until(listener, 3, timeout=30))
    assert all(line.startswith("hello ") for line in lines)


def test_rosnode_list_info_ping_and_cleanup(our_master: str, procs: Processes) -> None:
    env = ros_env(our_master, procs.tmp)
    talker = procs.python(TALKER, env)
    wait_until(lambda: "/talker" in graph_nodes(our_master))
    assert "/talker" in run(["rosnode", "list"], env).split()
    info = run(["rosnode", "info", "/talker"], env)
    assert "/chatter [std_msgs/String]" in info
    assert "reply from" in run(["rosnode", "ping", "-c", "1", "/talker"], env)
    procs.stop(talker)  # SIGTERM: rospy unregisters
    talker = procs.python(TALKER.replace('"talker"', '"doomed"'), env)
    wait_until(lambda: "/doomed" in graph_nodes(our_master))
    talker.kill()  # SIGKILL: the registration stays behind until our cleaner's next sweep or rosnode cleanup
    talker.wait(10)
    run(["rosnode", "cleanup"], env, stdin="y\n")
    assert "/doomed" not in graph_nodes(our_master)


SERVICE = textwrap.dedent(
    """
    import rospy
    from std_srvs.srv import SetBool, SetBoolResponse
    rospy.init_node("setter")
    rospy.Service("set_flag", SetBool, lambda req: SetBoolResponse(success=req.data, message="got %s" % req.data))
    print("ready", flush=True)
    rospy.spin()
    """
)


def test_a_rospy_service_answers_rosservice_call(our_master: str, procs: Processes) -> None:
    env = ros_env(our_master, procs.tmp)
    server = procs.python(SERVICE, env)
    assert list(iter_lines_until(server, 1, timeout=30)) == ["ready"]
    assert "/set_flag" in run(["rosservice", "list"], env).split()
    out = yaml.safe_load(run(["rosservice", "call", "/set_flag", "data: true"], env))
    assert out == {"success": True, "message": "got True"}


ROSCPP_TALKER = r"""
#include <ros/ros.h>
#include <std_msgs/String.h>
int main(int argc, char** argv) {
  ros::init(argc, argv, "cpp_talker");
  ros::NodeHandle nh;
  ros::Publisher pub = nh.advertise<std_msgs::String>("cpp_chatter", 10);
  ros::Rate rate(20);
  while (ros::ok()) {
    std_msgs::String msg; msg.data = "from cpp";
    pub.publish(msg);
    ros::spinOnce();
    rate.sleep();
  }
}
"""


def test_a_roscpp_node_publishes_to_rostopic_echo(our_master: str, procs: Processes, tmp_path: Path) -> None:
    if shutil.which("g++") is None or shutil.which("pkg-config") is None:
        pytest.skip("g++ or pkg-config is not installed")
    flags = subprocess.run(
        ["pkg-config", "--cflags", "--libs", "roscpp", "std_msgs"], capture_output=True, text=True, check=False
    )
    if flags.returncode != 0:
        pytest.skip(f"roscpp development files are missing: {flags.stderr.strip()}")
    src = tmp_path / "talker.cpp"
    src.write_text(ROSCPP_TALKER)
    exe = tmp_path / "cpp_talker"
    build = subprocess.run(
        ["g++", "-O0", "-o", str(exe), str(src), *flags.stdout.split()],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    if build.returncode != 0:
        pytest.skip(f"cannot compile a roscpp node: {build.stderr[-500:]}")
    env = ros_env(our_master, procs.tmp)
    procs.start([str(exe)], env)
    echo = procs.start(["rostopic", "echo", "/cpp_chatter"], env)
    assert list(iter_lines_until(echo, 1, timeout=30)) == ['data: "from cpp"']
    assert "/cpp_talker" in graph_nodes(our_master)


def test_a_second_rospy_node_with_the_same_name_shuts_the_first_one_down(our_master: str, procs: Processes) -> None:
    env = ros_env(our_master, procs.tmp)
    first = procs.python(TALKER, env)
    wait_until(lambda: "/talker" in graph_nodes(our_master))
    procs.python(TALKER, env)
    first.wait(20)  # rospy exits when the master tells it to shut down
    wait_until(lambda: "/talker" in graph_nodes(our_master))
