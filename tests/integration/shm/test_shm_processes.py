"""The shared-memory transport between processes: integrity for four subscribers, drops, SIGKILL of either side."""

from __future__ import annotations

import json
import os
import random
import signal
import time

from tests.integration.shm.conftest import (
    command,
    fd_kinds,
    held_rings,
    read_line,
    result,
    start_pub,
    start_sub,
)
from tests.rosenv import Processes


def wait_gone(pids: set[int], timeout: float = 10.0) -> None:
    """Until none of ``pids`` holds a ring (bounded)."""
    deadline = time.monotonic() + timeout
    while (held := held_rings(pids)) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not held, f"rings still held: {held}"


def test_four_subscribers_get_every_message_intact_through_a_growing_ring(procs: Processes) -> None:
    # Integrity and order, with a queue that holds the whole burst: no subscriber is given up on. With the
    # default STALL (50 ms), a subscriber process the loaded CI machine left unscheduled that long lost its
    # oldest four (that policy has tests of its own: test_shm_endpoint, test_a_stalled_subscriber_...).
    pub, address, token = start_pub(procs, "--subs", "4", "--size", "300000", "--queue", "200", "--stall", "60")
    subs = [
        start_sub(procs, address, token, "--expect", "40", *(["--zero-copy"] if i == 3 else []), hold=True)
        for i in range(4)
    ]
    read_line(pub, "attached")
    command(pub, "go 40")
    assert read_line(pub, "published") == "40"
    for sub in subs:
        res = result(sub)
        assert res == {**res, "got": 40, "dropped": 0, "bad": 0, "ordered": True, "first": 1, "last": 40}
    stats = json.loads(read_line(pub, "stats"))
    assert sorted(s["messages"] for s in stats) == [40] * 4
    assert all(s["bytes"] == 40 * 300000 and s["dropped"] == 0 for s in stats)
    for sub in subs:
        command(sub, "")
        assert read_line(sub, "leftover") == "0"
    pub.stdin.close()  # type: ignore[union-attr]
    pub.wait(10)
    wait_gone({p.pid for p in [pub, *subs]})


def test_a_late_subscriber_of_a_latched_topic_gets_the_last_message_first(procs: Processes) -> None:
    _pub, address, token = start_pub(procs, "--latch", "--size", "1000")
    sub = start_sub(procs, address, token, "--expect", "0")
    assert result(sub)["first"] == 0


def test_a_stalled_subscriber_loses_the_oldest_and_never_blocks_the_publisher(procs: Processes) -> None:
    pub, address, token = start_pub(procs, "--subs", "2", "--size", "5000", "--queue", "4")
    fast = start_sub(procs, address, token, "--expect", "100", hold=True)
    slow = start_sub(procs, address, token, "--expect", "100", hold=True)
    read_line(pub, "attached")
    os.kill(slow.pid, signal.SIGSTOP)
    try:
        command(pub, "go 100")
        assert read_line(pub, "published") == "100"  # while the slow one is stopped
        # a live subscriber gets every message it keeps up with (a 5-slot ring, a publisher in a tight loop)
        quick = result(fast)
        assert quick["bad"] == 0 and quick["ordered"] and quick["last"] == 100
        assert quick["got"] + quick["dropped"] == 100
    finally:
        os.kill(slow.pid, signal.SIGCONT)
    res = result(slow)
    assert res["bad"] == 0 and res["ordered"] and res["last"] == 100
    assert res["got"] <= 5 and res["got"] + res["dropped"] == 100
    read_line(pub, "stats")
    command(pub, "go 0")
    stats = json.loads(read_line(pub, "stats"))
    assert sorted(s["dropped"] for s in stats) == sorted([quick["dropped"], res["dropped"]])


def test_sigkill_of_the_publisher_mid_stream_ends_the_subscribers_cleanly(procs: Processes) -> None:
    for size in ("64", "1000000"):
        pub, address, token = start_pub(procs, "--subs", "2", "--size", size, "--queue", "8")
        subs = [start_sub(procs, address, token, "--expect", "1000000000") for _ in range(2)]
        read_line(pub, "attached")
        command(pub, "go 1000000")
        time.sleep(random.uniform(0.05, 0.3))
        os.kill(pub.pid, signal.SIGKILL)
        for sub in subs:
            res = result(sub)
            assert res["closed"] and res["bad"] == 0 and res["ordered"]
            assert read_line(sub, "leftover") == "0"
        wait_gone({p.pid for p in [pub, *subs]})


def test_sigkill_of_a_subscriber_frees_its_sockets_and_the_publisher_goes_on(procs: Processes) -> None:
    pub, address, token = start_pub(procs, "--subs", "2", "--size", "200000", "--queue", "8")
    victim = start_sub(procs, address, token, "--expect", "1000000000")
    keeper = start_sub(procs, address, token, "--expect", "60", hold=True)
    read_line(pub, "attached")
    sockets = sum(kind.startswith("socket:") for kind in fd_kinds(pub.pid))
    ack_pages = sum("mrosd-shm-ack" in kind for kind in fd_kinds(pub.pid))
    command(pub, "go 30")
    time.sleep(random.uniform(0.0, 0.1))
    os.kill(victim.pid, signal.SIGKILL)
    assert read_line(pub, "published") == "30"
    read_line(pub, "stats")
    command(pub, "go 30")
    assert read_line(pub, "published") == "60"
    stats = json.loads(read_line(pub, "stats"))
    assert len(stats) == 1, "the killed subscriber's link is gone"
    # its control socket, our end of its wake-up pair and its acknowledgement page are gone
    assert sum(kind.startswith("socket:") for kind in fd_kinds(pub.pid)) == sockets - 2
    assert sum("mrosd-shm-ack" in kind for kind in fd_kinds(pub.pid)) == ack_pages - 1 == 1  # mmap's own dup
    res = result(keeper)
    assert res["last"] == 60 and res["bad"] == 0 and res["ordered"]
    command(keeper, "")
    assert read_line(keeper, "leftover") == "0"
    victim.wait(5)
    pub.stdin.close()  # type: ignore[union-attr]
    pub.wait(10)
    wait_gone({pub.pid, victim.pid, keeper.pid})
