"""A publisher or subscriber process of the shared-memory transport, driven by the tests over stdin/stdout.

    shmnode.py pub --subs N [--size S] [--queue Q] [--latch] [--stall SECONDS]
        prints ``addr ADDRESS TOKEN``, then ``attached`` once N subscribers are; each stdin line ``go K``
        publishes K messages and prints ``published K`` and ``stats JSON``; stdin EOF closes it. ``--stall``
        replaces ``STALL``, how long a subscriber may hold back the others before its oldest messages go.
    shmnode.py sub ADDRESS TOKEN --expect K [--zero-copy]
        prints ``attached``; once K messages are received or dropped, or the publisher is gone, prints
        ``result JSON`` and, after closing, ``leftover N`` (its own fds and mappings of rings still open).

Message m is 8 bytes of m, then bytes of value m % 256, then 8 bytes of m (any tear or mix shows).
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import os
import stat
import sys

from mrosd import backports
from mrosd.shm import ShmPublisherEndpoint, ShmSubscriberConnection, ShmView, parse_answer
from mrosd.shm import publisher as shm_publisher
from mrosd.shm.negotiate import PROTOCOL, VERSION
from mrosd.wire.header import ConnectionHeader


def body(m: int, size: int) -> bytes:
    tag = m.to_bytes(8, "little")
    return tag + bytes([m % 256]) * (size - 16) + tag


def check(data: bytes | memoryview) -> int | None:
    """The message number, or None if the bytes are not one whole message."""
    if len(data) < 16:
        return None
    m = int.from_bytes(data[:8], "little")
    if bytes(data[-8:]) != bytes(data[:8]):
        return None
    middle = data[8:-8]
    if len(middle) and bytes(middle).count(m % 256) != len(middle):
        return None
    return m


def leftovers() -> int:
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            if "mrosd-shm-" in os.readlink(f"/proc/self/fd/{fd}"):
                n += 1
        except OSError:
            pass
    with open("/proc/self/maps") as f:
        n += sum(1 for line in f if "mrosd-shm-" in line)
    return n


def say(*parts: object) -> None:
    print(*parts, flush=True)


async def stdin_lines() -> asyncio.StreamReader:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    return reader


def fail_on_loop_errors() -> None:
    """An exception escaping a callback (logged and ignored by asyncio) fails the test: this process exits."""

    def handler(loop: asyncio.AbstractEventLoop, context: dict[str, object]) -> None:
        say("loop-error", context.get("message"), repr(context.get("exception")))
        os._exit(3)

    asyncio.get_running_loop().set_exception_handler(handler)


async def pub(args: argparse.Namespace) -> None:
    fail_on_loop_errors()
    if args.stall is not None:
        shm_publisher.STALL = args.stall
    changed = asyncio.Event()
    ep = ShmPublisherEndpoint("/shm_test", queue_size=args.queue, latch=args.latch, on_change=changed.set)
    await ep.start()
    if args.latch:
        ep.publish(body(0, args.size))
    say("addr", ep.address, ep.token)
    while len(ep.links) < args.subs:
        changed.clear()
        await changed.wait()
    say("attached")
    lines = await stdin_lines()
    m = 0
    while line := await lines.readline():
        words = line.split()
        if words[:1] == [b"go"]:
            for _ in range(int(words[1])):
                m += 1
                ep.publish(body(m, args.size))
                await asyncio.sleep(0)
            say("published", m)
        await asyncio.sleep(0.2)  # let subscribers report their drops
        say("stats", json.dumps(ep.stats()))
    await ep.aclose()


async def sub(args: argparse.Namespace) -> None:
    fail_on_loop_errors()
    answer = parse_answer([PROTOCOL, VERSION, args.address, args.token])
    assert answer is not None
    numbers: list[int] = []
    bad = 0
    done = asyncio.Event()

    def on_frame(frame: bytes | ShmView) -> None:
        nonlocal bad
        data = frame.data if isinstance(frame, ShmView) else frame
        m = check(data)
        if isinstance(frame, ShmView) and not frame.intact():
            m = None if m is None else -1  # overwritten while we looked: not counted as received intact
        if m is None:
            bad += 1
        elif m >= 0:
            numbers.append(m)
        if numbers and numbers[-1] >= args.expect:
            done.set()

    header = ConnectionHeader(callerid=f"/sub{os.getpid()}", topic="/shm_test", md5sum="*", type="*")
    conn = await ShmSubscriberConnection.attach(answer, header, on_frame=on_frame, zero_copy=args.zero_copy)
    say("attached")
    conn.closed.add_done_callback(lambda _: done.set())
    await backports.wait_for(done.wait(), 60)
    ordered = all(a < b for a, b in itertools.pairwise(numbers))
    result = {
        "got": len(numbers),
        "dropped": conn.dropped,
        "bad": bad,
        "ordered": ordered,
        "last": numbers[-1] if numbers else None,
        "first": numbers[0] if numbers else None,
        "closed": conn.closed.done(),
        "error": conn.error,
    }
    say("result", json.dumps(result))
    if stat.S_ISFIFO(os.fstat(0).st_mode):
        await (await stdin_lines()).readline()  # a test holding our stdin decides when we detach
    await conn.aclose()
    say("leftover", leftovers())
    await asyncio.sleep(30 if args.linger else 0)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=["pub", "sub"])
    parser.add_argument("address", nargs="?")
    parser.add_argument("token", nargs="?")
    parser.add_argument("--subs", type=int, default=1)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--queue", type=int, default=100)
    parser.add_argument("--latch", action="store_true")
    parser.add_argument("--stall", type=float)
    parser.add_argument("--expect", type=int, default=1)
    parser.add_argument("--zero-copy", action="store_true")
    parser.add_argument("--linger", action="store_true")
    args = parser.parse_args()
    asyncio.run(pub(args) if args.role == "pub" else sub(args))


if __name__ == "__main__":
    main()
