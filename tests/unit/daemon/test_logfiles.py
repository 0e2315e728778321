"""The log files roscore users look for: paths, line formats, ``latest`` and rotation (real files, no daemon)."""

from __future__ import annotations

import asyncio
import logging
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.logfiles import RosoutLogFile, RunLogs, graph_lines, ros_log_root, rosout_line, rosout_startup_line


def test_the_log_directory_follows_rospkgs_rule() -> None:
    assert ros_log_root({"ROS_LOG_DIR": "/a", "ROS_HOME": "/b"}) == Path("/a")
    assert ros_log_root({"ROS_HOME": "/b"}) == Path("/b/log")
    assert ros_log_root({}) == Path(os.path.expanduser("~")) / ".ros" / "log"


def log(secs: int, nsecs: int, level: int, name: str, where: tuple[str, int, str], topics: list[str], text: str) -> Any:
    """A rosgraph_msgs/Log's fields (the line formatter reads nothing else)."""
    file, line, function = where
    stamp = SimpleNamespace(secs=secs, nsecs=nsecs)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=stamp),
        level=level,
        name=name,
        file=file,
        line=line,
        function=function,
        topics=topics,
        msg=text,
    )


def test_rosout_lines_are_the_rosout_nodes_lines() -> None:
    # Written by Debian's rosout (1.15.15) for a rospy node, byte for byte:
    real = "1795639868.613579511 INFO /talker26 [<string>:5(<module>)] [topics: /rosout] hello from talker26\n"
    msg = log(1795639868, 613579511, 2, "/talker26", ("<string>", 5, "<module>"), ["/rosout"], "hello from talker26")
    assert rosout_line(msg) == real
    fatal = log(1, 5, 16, "/n", ("f.py", 1, "g"), ["/a", "/b"], "m")
    assert rosout_line(fatal) == "1.000000005 FATAL /n [f.py:1(g)] [topics: /a, /b] m\n"
    assert rosout_line(log(1, 0, 3, "/n", ("f", 1, "g"), [], "m")) == "1.000000000 3 /n [f:1(g)] [topics: ] m\n"
    assert rosout_startup_line(1795639863_641266115) == "\n\n1795639863.641266115  Node Startup\n"


@given(
    st.lists(
        st.tuples(st.sampled_from(["/a", "/b"]), st.lists(st.sampled_from(["/n1", "/n2"]), unique=True)), max_size=3
    )
)
def test_graph_lines_report_each_registration_once(pubs: list[tuple[str, list[str]]]) -> None:
    state = [[[t, n] for t, n in dict(pubs).items()], [], []]
    added = graph_lines([[], [], []], state, lambda node: f"http://{node[1:]}:1/")
    assert len(added) == sum(len(n) for n in dict(pubs).values())
    assert all(line.startswith("+PUB [") for line in added)
    removed = graph_lines(state, [[], [], []], lambda node: "")
    assert [line.replace("-", "+", 1).split(" http")[0] for line in removed] == [a.split(" http")[0] for a in added]
    assert graph_lines(state, state, lambda node: "") == []


def test_graph_lines_read_like_rosmasters() -> None:
    old = [[["/chatter", ["/talker"]]], [], [["/srv", ["/talker"]]]]
    new = [[], [["/chatter", ["/listener"]]], []]
    apis = {"/talker": "http://h:1/", "/listener": "http://h:2/"}
    assert graph_lines(old, new, apis.__getitem__) == [
        "-PUB [/chatter] /talker http://h:1/",
        "-SERVICE [/srv] /talker http://h:1/",
        "+SUB [/chatter] /listener http://h:2/",
    ]


def test_a_run_gets_its_directory_and_latest_points_at_the_newest(tmp_path: Path) -> None:
    first = RunLogs(tmp_path / "log", "run-1", 1000, 2)
    first.open()
    second = RunLogs(tmp_path / "log", "run-2", 1000, 2)
    second.open()
    try:
        logging.getLogger("mrosd.test").warning("into master.log")
        assert (tmp_path / "log" / "latest").resolve() == tmp_path / "log" / "run-2"
        text = second.master_path.read_text()
        assert "[mrosd.test][WARNING] " in text and text.rstrip().endswith(": into master.log")
        assert sorted(p.name for p in (tmp_path / "log").iterdir()) == ["latest", "run-1", "run-2"]
    finally:
        asyncio.run(first.aclose())
        asyncio.run(second.aclose())
    logging.getLogger("mrosd.test").warning("after close: nowhere")
    assert "nowhere" not in second.master_path.read_text()


def test_a_latest_that_is_not_a_symlink_is_left_alone(tmp_path: Path) -> None:
    (tmp_path / "latest").mkdir()
    logs = RunLogs(tmp_path, "run", 1000, 1)
    logs.open()
    asyncio.run(logs.aclose())
    assert (tmp_path / "latest").is_dir() and not (tmp_path / "latest").is_symlink()
    assert logs.master_path.exists()


def test_rosout_log_rotates_by_size_keeping_numbered_backups(tmp_path: Path) -> None:
    path = tmp_path / "rosout.log"
    f = RosoutLogFile(path, max_bytes=300, backups=2)
    try:
        for i in range(40):
            f.write_record(log(1, 2, 2, "/n", ("f", i, "g"), ["/rosout"], f"record {i:02d}"))
    finally:
        f.close()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["rosout.log", "rosout.log.1", "rosout.log.2"]
    assert all(p.stat().st_size <= 300 for p in tmp_path.iterdir())
    assert "record 39" in path.read_text()  # the newest is in rosout.log, older ones in .1, .2
    assert "Node Startup" not in path.read_text()


def test_a_log_file_that_cannot_be_written_is_one_journal_line_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    f = RosoutLogFile(tmp_path / "rosout.log", max_bytes=10**6, backups=1)
    f._handler.stream.close()
    f._handler.stream = open("/dev/full", "w")  # noqa: SIM115  (a full disk: every flush fails with ENOSPC)
    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(secs=1, nsecs=0)),
        level=2,
        name="/n",
        file="f",
        line=1,
        function="g",
        topics=[],
        msg="lost",
    )
    for _ in range(3):
        f.write_record(msg)
    f.close()
    assert "Traceback" not in capsys.readouterr().err
    assert [r.getMessage() for r in caplog.records if r.name == "mrosd.logfiles"] == [
        f"cannot write {tmp_path / 'rosout.log'}: [Errno 28] No space left on device"
    ]


async def test_the_daemon_writes_no_files_with_dir_off_and_runs_without_an_unwritable_dir(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from mrosd.config import Config
    from mrosd.daemon import Daemon

    cfg = Config()
    cfg.master.host, cfg.master.port = "127.0.0.1", 0
    cfg.log.dir = "off"
    daemon = Daemon(cfg, master_only=True)
    await daemon.start()
    try:
        assert daemon.logs is None and daemon.run_id
    finally:
        await daemon.aclose()
    blocker = tmp_path / "file"
    blocker.write_text("")
    cfg.log.dir = str(blocker / "log")  # a directory under a file: cannot be created
    daemon = Daemon(cfg, master_only=True)
    await daemon.start()
    try:
        assert daemon.logs is None and daemon.master is not None
    finally:
        await daemon.aclose()
    cfg.log.dir = str(tmp_path / "log")
    caplog.set_level(logging.INFO, logger="mrosd")  # what [log] level = "info" sets up in the daemon
    daemon = Daemon(cfg, master_only=True)
    await daemon.start()
    try:
        assert daemon.logs is not None
        assert (tmp_path / "log" / "latest").resolve() == tmp_path / "log" / daemon.run_id
    finally:
        await daemon.aclose()
    assert "master listening on 127.0.0.1" in (tmp_path / "log" / "latest" / "master.log").read_text()


async def test_master_log_follows_registrations_as_rosmaster_writes_them(tmp_path: Path) -> None:
    import mrosd
    from mrosd.master import Master
    from mrosd.msg import get_message_class

    logs = RunLogs(tmp_path, "run", 10**6, 1)
    logs.open()
    try:
        async with Master(host="127.0.0.1", port=0) as master:
            logs.follow_graph(master.api)
            async with mrosd.Node("talker", master_uri=master.uri, argv=[], host="127.0.0.1", rosout=False) as n:
                await n.advertise("/chatter", get_message_class("std_msgs/String"))
                uri = n.uri
            for _ in range(200):  # the follower writes as the master's graph changes
                if "-PUB [/chatter]" in logs.master_path.read_text():
                    break
                await asyncio.sleep(0.01)
    finally:
        await logs.aclose()
    lines = [line.split(": ", 1)[1] for line in logs.master_path.read_text().splitlines() if "PUB" in line]
    assert lines == [f"+PUB [/chatter] /talker {uri}", f"-PUB [/chatter] /talker {uri}"]  # the URI outlives the node
