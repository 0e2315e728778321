"""The process's spare receive buffers: reused only when free, bounded in count, bytes, size and idle time."""

from __future__ import annotations

import asyncio
import threading
import time

from mrosd import backports
from mrosd.msg.runtime import FrameBuffer
from mrosd.wire.spares import SPARE_BYTES, SPARES, SparePool, spare_pool

KiB = 1024


class Clock:
    """A clock the test moves by hand (``SparePool`` reads the time through ``clock``)."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_kept_buffer_is_taken_again_only_once_nobody_holds_it() -> None:
    pool = SparePool()
    held = FrameBuffer(256 * KiB)
    pool.keep(held)
    assert pool.take(100 * KiB) is None  # its receiver still holds it
    ident = id(held)
    del held
    again = pool.take(100 * KiB)
    assert again is not None and id(again) == ident and len(pool) == 0 and pool.size == 0


def test_a_buffer_smaller_than_asked_is_not_taken() -> None:
    pool = SparePool()
    pool.keep(FrameBuffer(100 * KiB))
    assert pool.take(101 * KiB) is None and len(pool) == 1


def test_the_pool_keeps_at_most_its_count_and_bytes_oldest_dropped_first() -> None:
    pool = SparePool(max_count=3, max_bytes=1000 * KiB, max_spare=1000 * KiB)
    bufs = [FrameBuffer(300 * KiB) for _ in range(5)]
    for buf in bufs:
        pool.keep(buf)
    assert len(pool) == 3 and pool.size == 900 * KiB
    pool.keep(FrameBuffer(500 * KiB))  # four, then 1100 KiB: the oldest two go
    assert len(pool) == 2 and pool.size == 800 * KiB
    assert pool.take(400 * KiB) is not None  # the newest, nobody else holds it


def test_a_buffer_over_the_largest_spare_is_never_kept() -> None:
    pool = SparePool(max_spare=1000 * KiB)
    pool.keep(FrameBuffer(1001 * KiB))
    assert len(pool) == 0 and pool.size == 0 and pool.take(1001 * KiB) is None


def test_the_defaults_fit_a_few_camera_frames_and_no_huge_message() -> None:
    pool = spare_pool()
    assert pool is spare_pool() and pool.max_count == SPARES and pool.max_bytes == SPARE_BYTES
    assert 4 * 8 * 1024 * KiB <= SPARE_BYTES and pool.max_spare < 40 * 1024 * KiB


def test_buffers_not_reused_for_the_idle_time_are_released() -> None:
    clock = Clock()
    pool = SparePool(idle=2.0, clock=clock)
    pool.keep(FrameBuffer(100 * KiB))
    clock.now += 1.5
    pool.keep(FrameBuffer(200 * KiB))
    assert pool.release_idle() == 0.5  # the first is due in half a second
    clock.now += 0.5
    assert pool.release_idle() == 1.5 and len(pool) == 1 and pool.size == 200 * KiB
    clock.now += 1.5
    assert pool.release_idle() is None and len(pool) == 0 and pool.size == 0


def test_keeping_a_buffer_also_drops_those_gone_idle() -> None:
    clock = Clock()
    pool = SparePool(idle=2.0, clock=clock)
    pool.keep(FrameBuffer(100 * KiB))
    clock.now += 3
    pool.keep(FrameBuffer(100 * KiB))
    assert len(pool) == 1


def test_a_copy_refills_a_free_kept_buffer_and_is_kept_itself() -> None:
    pool = SparePool()
    first = pool.copy(memoryview(b"a" * 300 * KiB))
    assert isinstance(first, FrameBuffer) and first == b"a" * 300 * KiB and len(pool) == 1
    ident = id(first)
    del first
    second = pool.copy(memoryview(b"b" * 200 * KiB))  # a larger free one, cut to size
    assert id(second) == ident and second == b"b" * 200 * KiB and len(pool) == 1


def test_the_loop_gives_idle_buffers_back_while_the_process_is_quiet() -> None:
    pool = SparePool(idle=0.05)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        pool.keep(FrameBuffer(100 * KiB))
        pool.watch(loop)
        pool.watch(loop)  # one timer, however many deliveries ask
        async with backports.timeout(2):
            while len(pool):  # noqa: ASYNC110 - the pool's own timer empties it
                await asyncio.sleep(0.01)

    asyncio.run(main())
    assert pool.size == 0

    async def again() -> None:  # the loop that held the timer is closed: the next one takes it over
        pool.keep(FrameBuffer(100 * KiB))
        pool.watch(asyncio.get_running_loop())
        async with backports.timeout(2):
            while len(pool):  # noqa: ASYNC110
                await asyncio.sleep(0.01)

    asyncio.run(again())


def test_loops_of_several_threads_never_take_the_same_buffer() -> None:
    pool = SparePool(max_count=4)
    clashes: list[int] = []
    start = threading.Barrier(4)

    def run(mark: int) -> None:
        start.wait()
        for _ in range(500):
            buf = pool.take(64 * KiB)
            if buf is None:
                buf = FrameBuffer(64 * KiB)
            buf[0] = mark  # this thread's alone until kept again
            time.sleep(0)
            if buf[0] != mark:
                clashes.append(mark)
            pool.keep(buf)
            del buf

    threads = [threading.Thread(target=run, args=(mark,)) for mark in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert clashes == [] and len(pool) <= 4 and pool.size == len(pool) * 64 * KiB
