"""Our nodes log to /rosout as rospy nodes do, and the daemon's aggregator offers what roscore's rosout offers.

Checked with the real tools against real rosmaster: a rospy subscriber reads the rosgraph_msgs/Log records,
``rosnode info`` lists the publication and the logger services, ``rosservice call`` lists and sets logger
levels, ``rosparam get`` reads the parameters roscore sets.
"""

from __future__ import annotations

import asyncio
import json
import logging
import select
import subprocess
import xmlrpc.client
from collections.abc import Iterator
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class, get_service_class
from mrosd.rosout import ROSVERSION, RosoutAggregator
from tests.rosenv import ROS_PYTHON, Processes, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

#: Prints each rosgraph_msgs/Log on argv[1] from node argv[2] as one JSON line.
LOG_READER = """
import json, sys, rospy
from rosgraph_msgs.msg import Log
rospy.init_node("log_reader", anonymous=True)
def on(m):
    if m.name == sys.argv[2]:
        print(json.dumps(dict(level=m.level, name=m.name, msg=m.msg, file=m.file, function=m.function,
                              line=m.line, topics=sorted(m.topics), stamp=m.header.stamp.to_sec())), flush=True)
rospy.Subscriber(sys.argv[1], Log, on)
print("up", flush=True)
rospy.spin()
"""


@pytest.fixture(autouse=True)
def _restore_rosout_level() -> Iterator[None]:
    logger = logging.getLogger("rosout")
    level = logger.level
    yield
    logger.setLevel(level)


async def ros(procs: Processes, master: str, *argv: str) -> str:
    """Run a ROS command-line tool in a thread (our nodes answer it from this loop)."""
    env = ros_env(master, procs.tmp)
    out = await asyncio.to_thread(
        subprocess.run, argv, env=env, capture_output=True, text=True, timeout=60, check=False
    )
    assert out.returncode == 0, out.stderr
    return out.stdout


async def reader(procs: Processes, master: str, topic: str, node: str) -> subprocess.Popen[bytes]:
    proc = procs.start([ROS_PYTHON, "-c", LOG_READER, topic, node], ros_env(master, procs.tmp))
    assert proc.stdout is not None
    assert (await asyncio.to_thread(proc.stdout.readline)).strip() == b"up"
    return proc


async def records(proc: subprocess.Popen[bytes], count: int) -> list[dict[str, Any]]:
    # Plain buffered readline (iter_lines_until's select misses a second line already in the buffer).
    assert proc.stdout is not None
    lines = [await backports.wait_for(asyncio.to_thread(proc.stdout.readline), 20) for _ in range(count)]
    return [json.loads(line) for line in lines]


async def node_params(master: str) -> dict[str, Any]:
    def get() -> dict[str, Any]:
        with xmlrpc.client.ServerProxy(master) as proxy:
            return {k: proxy.getParam("/t", k)[2] for k in ("/rosversion", "/rosdistro", "/run_id")}

    return await asyncio.to_thread(get)


async def rosversion_d() -> str:
    """What roscore's launch sets /rosdistro to here (``rosversion -d``: $ROS_DISTRO, else Debian's "Debian")."""
    out = await asyncio.to_thread(
        subprocess.run, ["rosversion", "-d"], capture_output=True, text=True, timeout=60, check=True
    )
    return out.stdout


def log_a_line(node: mrosd.Node) -> int:
    node.log.warning("wheels at %d rpm", 42)
    return log_a_line.__code__.co_firstlineno + 1


async def test_a_nodes_log_records_reach_rosout_with_name_file_function_line_and_topics(
    rosmaster: str, procs: Processes
) -> None:
    async with mrosd.Node("mrosd_logger", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        await node.subscribe("/heard", mrosd.AnyMsg)
        proc = await reader(procs, rosmaster, "/rosout", "/mrosd_logger")
        await node.master.lookup_node("/mrosd_logger")
        pub = node.publishers["/rosout"]
        await pub.wait_for_subscribers(1, timeout=20)
        line = log_a_line(node)
        node.log.debug("not published: rosout's level is INFO, as in rospy")
        logging.getLogger("rosout").info("plain rosout logger, as rospy code uses it")
        logging.getLogger("mrosd.something").warning("library diagnostics stay local")
        first, second = await records(proc, 2)
        assert first == {
            "level": 4,
            "name": "/mrosd_logger",
            "msg": "wheels at 42 rpm",
            "file": "test_rosout_interop.py",
            "function": "log_a_line",
            "line": line,
            "topics": ["/heard", "/rosout"],
            "stamp": first["stamp"],
        }
        assert first["stamp"] > 0
        assert (second["level"], second["msg"]) == (2, "plain rosout logger, as rospy code uses it")

        info = await ros(procs, rosmaster, "rosnode", "info", "/mrosd_logger")
        assert "* /rosout [rosgraph_msgs/Log]" in info
        assert "* /mrosd_logger/get_loggers" in info and "* /mrosd_logger/set_logger_level" in info

        loggers = await ros(procs, rosmaster, "rosservice", "call", "/mrosd_logger/get_loggers")
        assert 'name: "rosout"' in loggers
        await ros(
            procs, rosmaster, "rosservice", "call", "/mrosd_logger/set_logger_level", "{logger: rosout, level: debug}"
        )
        assert logging.getLogger("rosout").level == logging.DEBUG
        node.log.debug("now published")
        (third,) = await records(proc, 1)
        assert (third["level"], third["msg"]) == (1, "now published")
        await asyncio.to_thread(node.log.error, "from another thread")  # handed to the node's loop
        (fourth,) = await records(proc, 1)
        assert (fourth["level"], fourth["msg"]) == (8, "from another thread")


async def test_rosout_can_be_turned_off(rosmaster: str) -> None:
    async with mrosd.Node(
        "quiet", master_uri=rosmaster, argv=[], host="127.0.0.1", rosout=False, logger_services=False
    ) as node:
        assert "/rosout" not in node.publishers and not node.services


async def test_the_aggregator_offers_what_roscores_rosout_offers(rosmaster: str, procs: Processes) -> None:
    async with RosoutAggregator(rosmaster):
        params = await node_params(rosmaster)
        assert params["/rosversion"] == ROSVERSION + "\n"  # with the newline of `rosversion roslaunch`, as roscore
        assert params["/rosdistro"] == await rosversion_d()  # as roscore's launch sets it, newline included
        assert len(params["/run_id"]) == 36
        info = await ros(procs, rosmaster, "rosnode", "info", "/rosout")
        publications = info.split("Publications:")[1].split("Subscriptions:")[0]
        assert publications.split() == ["*", "/rosout_agg", "[rosgraph_msgs/Log]"]
        assert "* /rosout/get_loggers" in info and "* /rosout/set_logger_level" in info
        assert "loggers:" in await ros(procs, rosmaster, "rosservice", "call", "/rosout/get_loggers")

        proc = await reader(procs, rosmaster, "/rosout_agg", "/talker")
        async with mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
            for _ in range(100):  # until the aggregator and the reader are connected (the first lines may be lost)
                node.log.info("through the aggregator")
                await asyncio.sleep(0.1)
                if select.select([proc.stdout], [], [], 0)[0]:  # nothing read yet: the fd is the whole truth
                    break
            (rec,) = await records(proc, 1)
        assert rec["msg"] == "through the aggregator"


def test_the_roscpp_logger_types_match_genpys() -> None:
    # Debian ships roscpp's types only as generated Python (python3-roscpp-msg): compare with those.
    code = (
        "import json, roscpp.msg as m, roscpp.srv as s; print(json.dumps([c._md5sum for c in "
        "(s.GetLoggers, s.GetLoggersRequest, s.GetLoggersResponse, s.SetLoggerLevel, s.SetLoggerLevelRequest, "
        "s.SetLoggerLevelResponse, m.Logger)] + [c._full_text for c in "
        "(m.Logger, s.GetLoggersResponse, s.SetLoggerLevelRequest, s.SetLoggerLevelResponse)]))"
    )
    out = subprocess.run([ROS_PYTHON, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    get_loggers, set_level = get_service_class("roscpp/GetLoggers"), get_service_class("roscpp/SetLoggerLevel")
    logger = get_message_class("roscpp/Logger")
    ours = [
        get_loggers._md5sum,
        get_loggers._request_class._md5sum,
        get_loggers._response_class._md5sum,
        set_level._md5sum,
        set_level._request_class._md5sum,
        set_level._response_class._md5sum,
        logger._md5sum,
        logger._full_text,
        get_loggers._response_class._full_text,
        set_level._request_class._full_text,
        set_level._response_class._full_text,
    ]
    assert ours == json.loads(out.stdout)
