"""Leases on shared-memory slots (issue 25) cannot be turned against the publisher or the other subscribers.

A subscriber killed while it holds leases frees them (its control socket closing is the signal): the
publisher keeps its rate and every slot is written again. A hostile subscriber that writes lease words for
every message, far beyond its grant, and never acknowledges anything keeps at most its grant of slots: an
honest subscriber gets every message and the publisher never waits. A trusted uid other than ours attaching
again and again gets half of the lease slots at most (root: a second uid). Loaned messages keep the ring's rules:
a loan never takes a leased slot, and the pool stays unwritable by subscribers.
"""

from __future__ import annotations

import asyncio
import mmap
import os
import signal
import subprocess
import sys
import time
from typing import Any

import pytest

from mrosd import backports
from mrosd.shm import ShmPublisherEndpoint, ShmSubscriberConnection
from mrosd.shm.negotiate import VERSION, ShmAnswer
from mrosd.shm.segment import MAX_LEASES
from mrosd.wire.header import ConnectionHeader
from tests.integration.ixm.hostile import Child, nobody

HEADER = ConnectionHeader(callerid="/victim", topic="/t", md5sum="*", type="*")

#: a subscriber process that takes two leases, says so, and keeps them until it is killed
HOLDER = """
import asyncio, sys
from mrosd.shm import ShmSubscriberConnection
from mrosd.shm.negotiate import VERSION, ShmAnswer
from mrosd.wire.header import ConnectionHeader

async def main():
    held = []
    done = asyncio.Event()
    def keep(view):
        held.append(view)
        if len(held) == 2:
            done.set()
    answer = ShmAnswer(version=VERSION, address=sys.argv[1], token=sys.argv[2])
    header = ConnectionHeader(callerid="/holder", topic="/t", md5sum="*", type="*")
    await ShmSubscriberConnection.attach(answer, header, on_frame=keep, zero_copy=True, max_leased=2)
    print("attached", flush=True)
    await done.wait()
    print("held", " ".join(str(v.number) for v in held), flush=True)
    await asyncio.sleep(60)

asyncio.run(main())
"""


def answer(ep: ShmPublisherEndpoint) -> ShmAnswer:
    return ShmAnswer(version=VERSION, address=ep.address, token=ep.token)


async def line(proc: subprocess.Popen[bytes], prefix: str) -> str:
    assert proc.stdout is not None
    loop = asyncio.get_running_loop()
    async with backports.timeout(20):
        while True:
            got = (await loop.run_in_executor(None, proc.stdout.readline)).decode()
            if not got:
                raise AssertionError(f"the holder ended before {prefix!r}")
            if got.startswith(prefix):
                return got[len(prefix) :].strip()


async def test_a_subscriber_killed_with_leases_held_frees_its_slots_and_the_rate_holds() -> None:
    size = 256 << 10
    ep = ShmPublisherEndpoint("/t", queue_size=4, max_message_size=size, lease_slots=2)
    await ep.start()
    got: list[int] = []
    proc = subprocess.Popen(  # noqa: ASYNC220 - started once, before the loop has work
        [sys.executable, "-c", HOLDER, ep.address, ep.token], stdout=subprocess.PIPE, start_new_session=True
    )
    try:
        await line(proc, "attached")
        honest = await ShmSubscriberConnection.attach(answer(ep), HEADER, on_frame=lambda b: got.append(b[0]))
        assert ep.ring is not None
        slots = ep.ring.layout.slots
        worst = 0.0
        sent = 0

        async def publish(count: int) -> None:
            nonlocal worst, sent
            for _ in range(count):
                t0 = time.perf_counter()
                ep.publish(bytes([sent % 251]) * size)
                worst = max(worst, time.perf_counter() - t0)
                sent += 1
                await asyncio.sleep(0.002)

        await publish(2)
        held = [int(n) for n in (await line(proc, "held")).split()]
        await publish(3 * slots)  # laps the ring: the two leased slots are skipped, never written
        holder = next(lk for lk in ep.links if lk.callerid == "/holder")
        assert sorted(holder.leases()) == held
        layout = ep.ring.layout
        assert sorted(n for n in (layout.held(s) for s in range(slots)) if n in held) == held
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        async with backports.timeout(5):
            while any(lk.callerid == "/holder" for lk in ep.links):  # noqa: ASYNC110 - the socket closing
                await asyncio.sleep(0.005)
        before = layout.head
        t0 = time.monotonic()
        await publish(3 * slots)
        rate = 3 * slots / (time.monotonic() - t0)
        assert all(layout.held(s) > before for s in range(slots))  # every slot came back and was written
        assert worst < 0.05  # no publish call waited for anyone (256 KiB copies: well under a millisecond)
        assert rate > 100  # one every 2 ms asked for: the holder's death does not slow the publisher
        async with backports.timeout(5):
            while len(got) < sent:  # noqa: ASYNC110 - filled by the connection's callback
                await asyncio.sleep(0.005)
        assert got == [i % 251 for i in range(sent)] and honest.dropped == 0
        await honest.aclose()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        assert proc.stdout is not None
        proc.stdout.close()
        await ep.aclose()


async def test_a_hostile_subscriber_keeps_at_most_its_grant_of_slots() -> None:
    ep = ShmPublisherEndpoint("/t", queue_size=4, max_message_size=64 << 10, lease_slots=3)
    await ep.start()
    hostile = await ShmSubscriberConnection.attach(answer(ep), HEADER, zero_copy=True, max_leased=MAX_LEASES)
    got: list[bytes] = []
    honest = await ShmSubscriberConnection.attach(answer(ep), HEADER, on_frame=lambda b: got.append(bytes(b)))
    late = await ShmSubscriberConnection.attach(answer(ep), HEADER, zero_copy=True, max_leased=2)
    try:
        assert hostile.max_leased == 3 and late.max_leased == 0  # the pool's lease slots: first come
        assert ep.ring is not None and hostile._ack is not None
        layout = ep.ring.layout
        page = hostile._ack.word
        sent = [i.to_bytes(4, "little") * 1000 for i in range(200)]
        for body in sent:
            # it claims every message there is, in every lease word of its page, and acknowledges nothing
            head = layout.head
            for w in range(1, MAX_LEASES + 1):
                page[w] = max(1, head - w + 1)
            page[0] = 1
            t0 = time.perf_counter()
            ep.publish(body)
            assert time.perf_counter() - t0 < 0.05 and len(ep.backlog) <= 5
            kept = {n for n in (layout.held(s) for s in range(layout.slots)) if n and n <= head - layout.slots}
            assert len(kept) <= 3  # older than a whole ring and still there: only what its grant protects
            await asyncio.sleep(0.001)
        async with backports.timeout(10):
            while len(got) < len(sent):  # noqa: ASYNC110 - filled by the connection's callback
                await asyncio.sleep(0.01)
        assert got == sent and honest.dropped == 0
    finally:
        await hostile.aclose()
        await honest.aclose()
        await late.aclose()
        await ep.aclose()


async def test_a_declared_pool_with_a_loan_out_is_still_unwritable_by_subscribers() -> None:
    ep = ShmPublisherEndpoint("/t", queue_size=4, max_message_size=64 << 10)
    await ep.start()
    sub = await ShmSubscriberConnection.attach(answer(ep), HEADER, zero_copy=True)
    try:
        assert ep.ring is not None
        lent = ep.loan_slot(1000)
        assert lent is not None
        fd = ep.ring.reader_fd()  # what a subscriber receives
        try:
            with pytest.raises(PermissionError):
                mmap.mmap(fd, ep.ring.size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            rw = os.open(f"/proc/self/fd/{fd}", os.O_RDWR)  # same uid: the open itself succeeds
            try:
                with pytest.raises(PermissionError):
                    os.pwrite(rw, b"evil", 0)
                with pytest.raises(PermissionError):
                    mmap.mmap(rw, ep.ring.size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            finally:
                os.close(rw)
        finally:
            os.close(fd)
        assert sub._ring is not None
        with pytest.raises(TypeError):
            sub._ring.layout.data[0][0] = 1  # its mapping is read-only
        ep.end_loan(*lent)
    finally:
        await sub.aclose()
        await ep.aclose()


def lease_hoarder(address: str, token: str) -> Any:
    """Attach to the pool twice, asking for every lease each time; report the grants (runs as another uid)."""

    def run(report: Any) -> dict[str, Any]:
        async def main() -> list[int]:
            conns = [
                await ShmSubscriberConnection.attach(
                    ShmAnswer(version=VERSION, address=address, token=token),
                    HEADER,
                    zero_copy=True,
                    max_leased=MAX_LEASES,
                    trusted=frozenset({0}),
                )
                for _ in range(2)
            ]
            grants = [c.max_leased for c in conns]
            report({"grants": grants})  # holds its connections until the parent says go
            for c in conns:
                await c.aclose()
            return grants

        return {"grants": asyncio.run(main())}

    return run


@pytest.mark.root
async def test_a_trusted_foreign_uid_cannot_take_every_lease_slot() -> None:
    attacker = nobody()
    ep = ShmPublisherEndpoint(
        "/t", queue_size=4, max_message_size=64 << 10, lease_slots=4, trusted=frozenset({0, attacker.pw_uid})
    )
    await ep.start()
    child = Child(attacker, lease_hoarder(ep.address, ep.token))
    try:
        first = await asyncio.to_thread(child.line)
        assert first == {"grants": [2, 0]}  # that uid's share: half of the lease slots, however often it attaches
        ours = await ShmSubscriberConnection.attach(answer(ep), HEADER, zero_copy=True, max_leased=2)
        assert ours.max_leased == 2  # the rest is still there for our own uid
        await ours.aclose()
    finally:
        child.close()
        await ep.aclose()
