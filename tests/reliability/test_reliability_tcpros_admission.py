"""A node's TCPROS port under connection floods: admission before allocation, accept loops that back off.

The victim is a real node process (tests/reliability/floods.py) on asyncio's loop and on uvloop; the attacker
is another process with plain sockets and a descriptor limit of its own. Whatever the flood, a subscriber
that arrives during it receives messages, the node's memory follows the bytes the attacker sent (never the
lengths it claimed), and the node's log stays far below 1000 lines a minute.
"""

from __future__ import annotations

import asyncio
import resource
import struct
import time
import xmlrpc.client
from pathlib import Path

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class, get_service_class
from tests.integration.ixm.hostile import cpu_seconds, rss_kib
from tests.integration.ixm.hostile import fd_count as open_fds
from tests.reliability.floods import flood_result, get_pid, start_flood, start_talker
from tests.reliability.relnodes import node_env, start_master
from tests.rosenv import Processes

String = get_message_class("std_msgs/String")

LOOPS = ["asyncio", "uvloop"]

#: The bar: a node's RSS grows less than this under 10,000 half-open connections.
RSS_BOUND_KIB = 100 * 1024
HALF_OPEN = 10_000
#: The bar: at most 1000 log lines a minute from one attacker.
LINES_PER_MINUTE = 1000


async def _receives(uri: str, topic: str, name: str, count: int, timeout: float) -> int:
    """Subscribe with a fresh node and return how many messages arrive (stops at ``count`` or ``timeout``)."""
    got: list[str] = []
    done = asyncio.Event()

    def on_message(msg: object) -> None:
        got.append(str(getattr(msg, "data", "")))
        if len(got) >= count:
            done.set()

    async with mrosd.Node(name, master_uri=uri, host="127.0.0.1", argv=[], rosout=False) as node:
        await node.subscribe(topic, String, callback=on_message)
        try:
            await backports.wait_for(done.wait(), timeout)
        except TimeoutError:
            pass
    return len(got)


async def _service_answers(uri: str, service: str) -> int:
    """Call ``service`` (roscpp/GetLoggers, which every node offers) with a fresh node: loggers listed."""
    srv: object = get_service_class("roscpp/GetLoggers")
    async with mrosd.Node("legit_caller", master_uri=uri, host="127.0.0.1", argv=[], rosout=False) as node:
        proxy = node.service_proxy(service, srv)
        reply = await proxy.call(srv._request_class(), timeout=10.0)  # type: ignore[attr-defined]
    return len(reply.loggers)


def _log_lines(path: Path) -> int:
    return len(path.read_bytes().splitlines())


@pytest.mark.parametrize("loop", LOOPS)
async def test_half_open_headers_cost_what_they_send(procs: Processes, tmp_path: Path, loop: str) -> None:
    """10,000 connections each claim a 4 MiB header, send one byte of it and hold: the node's RSS stays flat."""
    _, uri = start_master(procs)
    talker, port, log_path = start_talker(procs, node_env(uri, tmp_path), tmp_path, "/half_open", loop=loop)
    assert await _receives(uri, "/half_open", "warmup", 3, 10.0) == 3
    before = rss_kib(talker.pid)
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    count = min(HALF_OPEN, hard - 200)
    flood = start_flood(procs, port, count, struct.pack("<I", 4 * 1024 * 1024) + b"x", 20.0)
    # The subscriber's connection queues behind the whole flood (the kernel's accept queue is FIFO): once it
    # receives, the node has accepted and read every half-open connection.
    started = time.monotonic()
    assert await _receives(uri, "/half_open", "legit", 5, 15.0) == 5, "no messages during the flood"
    assert await _service_answers(uri, "/flood_talker/get_loggers") > 0  # the service side shares the listener
    await asyncio.sleep(0.5)
    grown = rss_kib(talker.pid) - before
    fds = open_fds(talker.pid)
    procs.stop(flood)
    per_connection = grown / count
    assert per_connection * HALF_OPEN < RSS_BOUND_KIB, (
        f"RSS grew {grown} KiB for {count} half-open connections ({per_connection:.1f} KiB each)"
    )
    assert fds < 600, f"the node holds {fds} descriptors: header-less connections are not capped"
    elapsed = time.monotonic() - started
    lines = _log_lines(log_path)
    print(f"{loop}: {count} half-open: RSS +{grown} KiB, {fds} fds held, {lines} log lines in {elapsed:.1f} s")
    assert lines <= max(20, LINES_PER_MINUTE * elapsed / 60), f"{lines} log lines in {elapsed:.1f} s"


@pytest.mark.parametrize("loop", LOOPS)
async def test_a_partial_header_is_dropped_at_its_deadline(procs: Processes, tmp_path: Path, loop: str) -> None:
    """A header that never completes costs its connection a few seconds, not forever."""
    _, uri = start_master(procs)
    _, port, _ = start_talker(procs, node_env(uri, tmp_path), tmp_path, "/deadline", loop=loop)
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(struct.pack("<I", 100) + b"\x05\x00")
    await writer.drain()
    started = time.monotonic()
    try:
        assert await backports.wait_for(reader.read(), 15.0) == b""
    except ConnectionResetError:
        pass
    held = time.monotonic() - started
    writer.close()
    assert 1.0 < held < 10.0, f"held {held:.1f} s"


async def _idle_flood(procs: Processes, tmp_path: Path, loop: str, nofile: int, count: int) -> None:
    _, uri = start_master(procs)
    talker, port, log_path = start_talker(
        procs, node_env(uri, tmp_path), tmp_path, "/idle_flood", nofile=nofile, loop=loop
    )
    seconds = 8.0
    flood = start_flood(procs, port, count, b"", seconds, reconnect=True)
    started = time.monotonic()
    cpu = cpu_seconds(talker.pid)
    got = await _receives(uri, "/idle_flood", "legit", 20, 10.0)
    with xmlrpc.client.ServerProxy(uri) as master:
        _, _, slave_uri = master.lookupNode("/probe", "/flood_talker")
    answers = [await asyncio.to_thread(get_pid, slave_uri, 3.0) for _ in range(5)]
    held = open_fds(talker.pid)
    result = flood_result(flood, seconds + 20.0)
    elapsed = time.monotonic() - started
    used = cpu_seconds(talker.pid) - cpu
    lines = _log_lines(log_path)
    print(f"{loop}, nofile {nofile}: got {got}, {lines} lines, CPU {used:.1f} s in {elapsed:.1f} s, {result}")
    print(f"  the node's slave API during the flood: {[(code, round(t, 4)) for code, t in answers]}")
    assert all(code == 1 and took < 1.0 for code, took in answers), answers  # the reserve serves it
    assert got == 20, f"a new subscriber got {got} messages during the flood ({result}, {held} fds)"
    assert talker.poll() is None, log_path.read_text()[-2000:]
    assert lines <= LINES_PER_MINUTE * elapsed / 60, f"{lines} log lines in {elapsed:.1f} s"
    assert used < 0.9 * elapsed, f"the node used {used:.1f} s of CPU in {elapsed:.1f} s ({result})"


@pytest.mark.parametrize("loop", LOOPS)
async def test_an_idle_flood_beyond_the_fd_limit_locks_nobody_out(procs: Processes, tmp_path: Path, loop: str) -> None:
    """`ulimit -n 1024`, 1100 idle connections that reconnect as they drop: the node stays quiet and serves."""
    await _idle_flood(procs, tmp_path, loop, nofile=1024, count=1100)


@pytest.mark.parametrize("loop", LOOPS)
async def test_accept_backs_off_at_emfile(procs: Processes, tmp_path: Path, loop: str) -> None:
    """A descriptor limit below the header-less cap: accept hits EMFILE, pauses, sheds the oldest, resumes."""
    await _idle_flood(procs, tmp_path, loop, nofile=96, count=200)
