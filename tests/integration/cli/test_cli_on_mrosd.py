"""`mros` against mrosd's own master: parameters, graph queries and daemon status, over real sockets."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.rosenv import Processes, free_port, iter_lines_until, ros_env, wait_for_xmlrpc


@pytest.fixture
def mrosd_master(procs: Processes) -> str:
    port = free_port()
    procs.our_python(["-m", "mrosd.daemon", "--master-only", "--port", str(port)], stderr=subprocess.DEVNULL)
    uri = f"http://127.0.0.1:{port}/"
    wait_for_xmlrpc(uri)
    return uri


def mros(uri: str, *args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", uri, *args],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_parameters_round_trip_through_set_get_list_dump_load_delete(mrosd_master: str, tmp_path: Path) -> None:
    uri = mrosd_master
    assert mros(uri, "param", "set", "/robot", "{name: r2, arm: {joints: 6}, gains: [1.5, 2]}").returncode == 0
    assert mros(uri, "param", "set", "/neg", "-3").returncode == 0
    assert mros(uri, "param", "get", "/robot/arm/joints").stdout == "6\n"
    assert mros(uri, "param", "get", "/neg").stdout == "-3\n"
    assert mros(uri, "param", "list", "/robot").stdout == "/robot/arm/joints\n/robot/gains\n/robot/name\n"
    dumped = mros(uri, "param", "dump", "-", "/robot").stdout
    assert dumped == "arm:\n  joints: 6\ngains:\n- 1.5\n- 2\nname: r2\n"
    assert mros(uri, "param", "load", "-", "/copy", stdin=dumped).returncode == 0
    assert mros(uri, "param", "dump", "-", "/copy").stdout == dumped
    assert mros(uri, "param", "delete", "/robot").returncode == 0
    missing = mros(uri, "param", "get", "/robot")
    assert missing.returncode == 1
    assert missing.stderr == "ERROR: Parameter [/robot] is not set\n"  # rosparam get prints the same line


def test_daemon_status_reports_a_running_master_and_fails_for_a_dead_one(mrosd_master: str, tmp_path: Path) -> None:
    up = mros(mrosd_master, "daemon", "status", "--ixm-socket", str(tmp_path / "none.sock"))
    assert up.returncode == 0, up.stderr
    assert up.stdout.startswith(f"master: running at {mrosd_master} (pid ")
    down = mros(f"http://127.0.0.1:{free_port()}/", "daemon", "status")
    assert down.returncode == 1
    # rostopic/rosparam/rosnode: "ERROR: Unable to communicate with master!"; mros adds which URI and why
    assert down.stderr.startswith("ERROR: Unable to communicate with master!\n\ncannot reach the ROS master at ")


def test_graph_queries_on_an_empty_master_print_nothing_and_succeed(mrosd_master: str) -> None:
    for argv in (["node", "list"], ["topic", "list"], ["service", "list"]):
        out = mros(mrosd_master, *argv)
        assert out.returncode == 0, (argv, out.stderr)
        assert out.stdout.strip() == "" or argv == ["node", "list"]


@pytest.mark.parametrize("shm", [None, "0"])
def test_topic_info_lists_the_connections_that_use_shared_memory(
    mrosd_master: str, procs: Processes, tmp_path: Path, shm: str | None
) -> None:
    """Two mrosd processes on one host share memory by default (not with MROSD_SHM=0); `topic info` says which
    connections do."""
    env = ros_env(mrosd_master, tmp_path)
    env.pop("MROSD_SHM", None)
    if shm is not None:
        env["MROSD_SHM"] = shm
    base = ["-m", "mros_cli.main", "--master-uri", mrosd_master, "topic"]
    procs.our_python([*base, "pub", "/shm_info", "std_msgs/String", "data: x", "-r", "20"], env)
    echo = procs.our_python([*base, "echo", "/shm_info"], env)
    assert next(iter_lines_until(echo, 1, 20.0)) == 'data: "x"'
    shown = subprocess.run(
        [sys.executable, *base, "info", "/shm_info"], env=env, capture_output=True, text=True, timeout=60, check=True
    ).stdout
    talker, listener = re.findall(r"^ \* (\S+) \(http", shown, re.MULTILINE)
    if shm is None:
        # the pool the topic holds, bounded and visible: slots x slot size = total
        pool = r"\(pid \d+; pool \d+ x \d+\.\d MiB = \d+\.\d MiB[^)]*\)"
        assert re.search(
            rf"/\)\n\nShared memory: \n \* {re.escape(talker)} -> {re.escape(listener)} {pool}\n\n\n$", shown
        ), shown
    else:
        assert "Shared memory" not in shown, shown
