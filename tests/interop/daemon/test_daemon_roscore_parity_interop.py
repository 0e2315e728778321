"""mrosd beside real roscore: the same log files (``latest/rosout.log``, ``latest/master.log``) in the same
formats, and the same parameters seeded at start.

Both run at once, each with its own ROS_LOG_DIR, and the same rospy node logs through /rosout to each.
"""

from __future__ import annotations

import re
import subprocess
import time
import xmlrpc.client
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros_env
from tests.rosenv import ROS_PYTHON, Processes, free_port, needs_ros, ros_env, wait_for_xmlrpc

pytestmark = [needs_ros, pytest.mark.interop]

#: Logs one line every 50 ms until killed (the first ones may go out before rosout is connected).
LOGGER = """
import rospy
rospy.init_node("logger26")
n = 0
while not rospy.is_shutdown():
    rospy.logwarn("hello %d", n)
    n += 1
    rospy.sleep(0.05)
"""

STAMP = re.compile(r"^\d+\.\d{9} ")
HELLO = re.compile(r"^\d+\.\d{9} WARN /logger26 \[<string>:6\(<module>\)\] \[topics: /rosout\] hello \d+$")
#: rosmaster's (rospy's logging) line: [logger][LEVEL] 2026-11-25 20:51:03,601: message
MASTER_LINE = re.compile(r"^\[[\w.]+\]\[(DEBUG|INFO|WARNING|ERROR|CRITICAL)\] \d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}: ")


def _wait(what: str, check: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.05)


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


def _params(uri: str) -> dict[str, str]:
    with xmlrpc.client.ServerProxy(uri) as master:
        names = master.getParamNames("/t")[2]
        return {n: master.getParam("/t", n)[2] for n in names if not n.startswith("/roslaunch/uris/")}


def _run_side(procs: Processes, uri: str, log_dir: Path) -> tuple[str, str, dict[str, str]]:
    """Log through /rosout until rosout.log has a line; return (rosout.log, master.log, parameters)."""
    logger = procs.start([ROS_PYTHON, "-c", LOGGER], ros_env(uri, procs.tmp), stdout=subprocess.DEVNULL)
    rosout = log_dir / "latest" / "rosout.log"
    _wait(f"a hello line in {rosout}", lambda: "hello" in _read(rosout))
    _wait(f"/logger26 in {log_dir}/latest/master.log", lambda: "/logger26" in _read(log_dir / "latest" / "master.log"))
    params = _params(uri)
    procs.stop(logger)
    assert (log_dir / "latest").is_symlink()
    assert (log_dir / "latest").resolve().name == params["/run_id"]  # the run's directory is named by /run_id
    return _read(rosout), _read(log_dir / "latest" / "master.log"), params


def test_mrosd_writes_roscores_log_files_and_seeds_roscores_parameters(procs: Processes, tmp_path: Path) -> None:
    ours_port, real_port = free_port(), free_port()
    ours_uri, real_uri = f"http://127.0.0.1:{ours_port}/", f"http://127.0.0.1:{real_port}/"
    real_logs, ours_logs = tmp_path / "real_log", tmp_path / "ours_log"
    procs.start(
        ["roscore", "-p", str(real_port)],
        ros_env(real_uri, tmp_path, ROS_LOG_DIR=str(real_logs)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    ours_env = mros_env(ours_uri, tmp_path)
    ours_env.update(ROS_LOG_DIR=str(ours_logs), MROSD_IXM_SOCKET=str(tmp_path / "ixm.sock"))
    procs.our_python(["-m", "mrosd.daemon", "--port", str(ours_port)], ours_env, stdout=subprocess.DEVNULL)
    wait_for_xmlrpc(ours_uri)
    wait_for_xmlrpc(real_uri, timeout=60)
    _wait("roscore's /rosdistro", lambda: "/rosdistro" in _params(real_uri), timeout=60)
    _wait("mrosd's /rosdistro", lambda: "/rosdistro" in _params(ours_uri))

    real_rosout, real_master, real_params = _run_side(procs, real_uri, real_logs)
    ours_rosout, ours_master, ours_params = _run_side(procs, ours_uri, ours_logs)

    # Parameters: the same names, the same /rosdistro and /rosversion (roscore's launch adds only its own
    # /roslaunch/uris/host_* entry, the URI of its roslaunch server, which mrosd does not run).
    assert sorted(ours_params) == sorted(real_params) == ["/rosdistro", "/rosversion", "/run_id"]
    assert ours_params["/rosdistro"] == real_params["/rosdistro"]
    assert ours_params["/rosversion"] == real_params["/rosversion"]

    # rosout.log: the start-up lines, then the node's records in the same format.
    for text in (real_rosout, ours_rosout):
        head, *records = text.split("\n")[2:]
        assert STAMP.match(head) and head.endswith("  Node Startup"), text[:200]
        hello = [r for r in records if "hello" in r]
        assert hello and all(HELLO.match(r) for r in hello), hello[:3]

    # master.log: every line in rosmaster's format, the node's registrations as rosmaster writes them.
    for text in (real_master, ours_master):
        lines = text.splitlines()
        assert lines and all(MASTER_LINE.match(line) for line in lines), lines[:3]
        assert re.search(r": \+PUB \[/rosout\] /logger26 http://127\.0\.0\.1:\d+/$", text, re.MULTILINE), text
        assert re.search(r": \+SERVICE \[/logger26/get_loggers\] /logger26 http://", text), text
