"""`mros bag record` and `mros bag play` against mrosd's master, with mrosd nodes on the other side.

What goes into the bag is the exact bytes each publisher sent, with its type, md5sum, definition, callerid
and latching flag; what play sends is the exact stored bytes, remapped, latched when stored latched.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path

import pytest

from mrosd import backports
from mrosd.bag.files import open_bag, open_writer
from mrosd.bag.model import ConnectionInfo
from mrosd.msg import get_message_class
from mrosd.tcpros import AnyMsg, Node
from tests.rosenv import Processes, free_port

String = get_message_class("std_msgs/String")
Int32 = get_message_class("std_msgs/Int32")
Clock = get_message_class("rosgraph_msgs/Clock")


@pytest.fixture
def master(procs: Processes) -> str:
    """mrosd's master on a free port; another port is tried when the daemon exits (the port was taken)."""
    for _attempt in range(3):
        port = free_port()
        daemon = procs.our_python(["-m", "mrosd.daemon", "--master-only", "--port", str(port)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        uri = f"http://127.0.0.1:{port}/"
        deadline = time.monotonic() + 30
        while daemon.poll() is None and time.monotonic() < deadline:
            try:
                with xmlrpc.client.ServerProxy(uri) as proxy:
                    proxy.getPid("/test")
                return uri
            except (OSError, xmlrpc.client.Error):
                time.sleep(0.05)
        if daemon.poll() is None:
            raise TimeoutError(f"mrosd's master at {uri} did not answer within 30 s")
    raise RuntimeError("mrosd's master exited on three free ports")


def mros_bag(procs: Processes, master: str, cwd: Path, *args: str) -> subprocess.Popen[bytes]:
    env = dict(os.environ, ROS_MASTER_URI=master, ROS_HOSTNAME="127.0.0.1")
    return procs.start([sys.executable, "-m", "mros_cli.main", "bag", *args], env | {"PWD": str(cwd)})


async def finish(proc: subprocess.Popen[bytes], timeout: float = 20.0) -> tuple[int, str]:
    _out, err = await asyncio.to_thread(proc.communicate, timeout=timeout)
    return proc.returncode, err.decode()


async def test_record_all_picks_up_a_topic_that_appears_later_and_stores_the_bytes_sent(
    procs: Processes, master: str, tmp_path: Path
) -> None:
    out = tmp_path / "all"
    rec = mros_bag(procs, master, tmp_path, "record", "-a", "-O", str(out), "--poll-interval", "0.1",
                   "--duration", "4", "--no-status")  # fmt: skip
    async with Node("talker", master_uri=master, argv=[]) as node:
        late = await node.advertise("/late", String)
        latched = await node.advertise("/latched", Int32, latch=True)
        await latched.publish(Int32(data=7))
        await late.wait_for_subscribers(1, timeout=10)  # the recorder found the new topic by itself
        sent = [String(data=f"message {i} " + "x" * i) for i in range(50)]
        for msg in sent:
            await late.publish(msg)
        code, err = await finish(rec)
    assert code == 0, err
    assert "Recorded" in err
    reader = open_bag(str(out) + ".bag")
    try:
        stored = [(c, data) for c, _t, data in reader.messages()]
    finally:
        reader.close()
    late_msgs = [data for c, data in stored if c.topic == "/late"]
    assert late_msgs == [m.serialize() for m in sent]
    conns = {c.topic: c for c, _ in stored}
    assert conns["/late"] == ConnectionInfo(
        "/late", "std_msgs/String", String._md5sum, String._full_text, "/talker", latching=False
    )
    assert conns["/latched"].latching
    assert [data for c, data in stored if c.topic == "/latched"] == [Int32(data=7).serialize()]


async def test_record_with_a_limit_ends_by_itself_and_splits_by_size(procs: Processes, master: str,
                                                                     tmp_path: Path) -> None:  # fmt: skip
    out = tmp_path / "split"
    async with Node("talker", master_uri=master, argv=[]) as node:
        pub = await node.advertise("/big", String)
        rec = mros_bag(procs, master, tmp_path, "record", "/big", "-l", "30", "-O", str(out), "--split",
                       "--size", "1", "--no-status")  # fmt: skip
        await pub.wait_for_subscribers(1, timeout=10)
        bodies = [String(data=chr(65 + i % 26) * 100_000) for i in range(30)]
        for msg in bodies:
            await pub.publish(msg)
        code, err = await finish(rec)
    assert code == 0, err
    files = sorted(await asyncio.to_thread(lambda: list(tmp_path.glob("split_*.bag"))))
    assert [f.name for f in files] == [f"split_{i}.bag" for i in range(len(files))]
    assert len(files) >= 2
    got = []
    for f in files:
        reader = open_bag(str(f))
        got.extend(data for _c, _t, data in reader.messages())
        reader.close()
    assert got == [m.serialize() for m in bodies]


async def test_record_shows_a_live_status_line_and_sigterm_leaves_a_complete_bag(
    procs: Processes, master: str, tmp_path: Path
) -> None:
    out = tmp_path / "live"
    async with Node("talker", master_uri=master, argv=[]) as node:
        pub = await node.advertise("/x", String)
        rec = mros_bag(procs, master, tmp_path, "record", "/x", "-O", str(out), "--status")
        await pub.wait_for_subscribers(1, timeout=10)
        for i in range(5):
            await pub.publish(String(data=str(i)))
        assert rec.stderr is not None
        seen = b""
        async with backports.timeout(10):  # the line is refreshed twice a second with the count so far
            while b": 5 msgs," not in seen:
                seen += await asyncio.to_thread(rec.stderr.read1, 4096)  # type: ignore[attr-defined]
        rec.send_signal(signal.SIGTERM)
        code, err = await finish(rec)
    assert code == 0, err
    assert f"Recording to {out}.bag: 5 msgs" in seen.decode()
    assert "Recorded 5 messages" in err
    assert not (tmp_path / "live.bag.active").exists()
    reader = open_bag(f"{out}.bag")
    assert [data for _c, _t, data in reader.messages()] == [String(data=str(i)).serialize() for i in range(5)]
    reader.close()

    quiet = mros_bag(procs, master, tmp_path, "record", "/x", "-O", str(tmp_path / "quiet"), "--duration", "0.5")
    code, err = await finish(quiet)
    assert code == 0, err
    assert "Recording to" not in err  # stderr is not a terminal: no live line unless --status


def write_sample(path: Path) -> list[bytes]:
    """Two topics 10 ms apart: /a (String, 20 messages) and /latched (Int32, one message, stored latched)."""
    writer = open_writer(str(path), "bag")
    a = writer.add_connection(ConnectionInfo("/a", "std_msgs/String", String._md5sum, String._full_text, "/rec"))
    lat = writer.add_connection(
        ConnectionInfo("/latched", "std_msgs/Int32", Int32._md5sum, Int32._full_text, "/rec", latching=True)
    )
    t0 = 1_700_000_000_000_000_000
    writer.write(lat, t0, Int32(data=42).serialize())
    bodies = [String(data=f"stored {i}").serialize() for i in range(20)]
    for i, body in enumerate(bodies):
        writer.write(a, t0 + (i + 1) * 10_000_000, body)
    writer.close()
    return bodies


async def test_play_publishes_the_stored_bytes_remapped_with_clock_from_a_start_offset(
    procs: Processes, master: str, tmp_path: Path
) -> None:
    bag = tmp_path / "s.bag"
    bodies = write_sample(bag)
    async with Node("listener", master_uri=master, argv=[]) as node:
        remapped = await node.subscribe("/renamed", AnyMsg, queue_size=1000)
        clock = await node.subscribe("/clock", Clock, queue_size=10000)
        play = mros_bag(procs, master, tmp_path, "play", str(bag), "/a:=/renamed", "--clock", "-s", "0.055",
                        "--topics", "/a", "--wait-for-subscribers", "-q")  # fmt: skip
        try:
            got = [await remapped.next(timeout=10) for _ in range(15)]
        finally:
            code, err = await finish(play)
        assert code == 0, err
        assert [m.data for m in got] == bodies[5:]  # -s 0.055: the first five /a messages are skipped
        assert got[0].header.type == "std_msgs/String"
        assert got[0].header.md5sum == String._md5sum
        ticks = []
        while clock._queue:
            ticks.append((await clock.next(timeout=1)).clock.to_nsec())
        assert ticks, "no /clock message"
        assert ticks == sorted(ticks)
        t0 = 1_700_000_000_000_000_000
        assert t0 + 55_000_000 <= ticks[0] and ticks[-1] <= t0 + 200_000_000


async def test_play_loops_latches_what_was_stored_latched_and_ends_on_sigint(
    procs: Processes, master: str, tmp_path: Path
) -> None:
    bag = tmp_path / "s.bag"
    bodies = write_sample(bag)
    async with Node("listener", master_uri=master, argv=[]) as node:
        sub = await node.subscribe("/a", AnyMsg, queue_size=1000)
        play = mros_bag(procs, master, tmp_path, "play", str(bag), "-l", "-r", "10", "-q")
        got: list[bytes] = []  # from the first whole pass on (a loaded machine connects later into the first)
        while bodies[0] not in got or len(got) - got.index(bodies[0]) < 2 * len(bodies):
            assert len(got) < 4 * len(bodies), got
            got.append((await sub.next(timeout=10)).data)
        assert got[got.index(bodies[0]) :] == bodies + bodies  # it plays the bag again and again
        async with Node("late", master_uri=master, argv=[]) as late_node:
            late = await late_node.subscribe("/latched", AnyMsg)
            msg = await late.next(timeout=10)  # a late subscriber still gets the latched message
            assert msg.data == Int32(data=42).serialize()
            assert msg.header.latching == "1"
        play.send_signal(signal.SIGINT)
        code, err = await finish(play)
    assert code == 0, err


def test_topic_echo_from_a_bag_prints_rostopic_text_and_bag_errors_are_one_line(tmp_path: Path) -> None:
    bag = tmp_path / "s.bag"
    write_sample(bag)

    def mros(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "mros_cli.main", *args], capture_output=True, text=True,
                              timeout=30, check=False)  # fmt: skip

    done = mros("topic", "echo", "-b", str(bag), "/a", "-n", "2")
    assert done.returncode == 0, done.stderr
    assert done.stdout == 'data: "stored 0"\n---\ndata: "stored 1"\n---\n'
    assert mros("topic", "echo", "-b", str(bag), "/latched/data").stdout == "42\n---\n"
    for args, error in [
        (("topic", "echo", "-b", str(bag), "/nope"), "has no topic /nope; it has: /a, /latched"),
        (("bag", "info", str(tmp_path / "nope.bag")), "cannot read"),
        (("bag", "play", str(tmp_path / "nope.bag")), "cannot read"),
    ]:
        failed = mros(*args)
        assert failed.returncode == 1
        assert failed.stderr.startswith("ERROR: ")
        assert error in failed.stderr
        assert len(failed.stderr.splitlines()) == 1
