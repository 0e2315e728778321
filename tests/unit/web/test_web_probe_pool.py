"""``ProbePool`` scheduling: global and per-peer bounds, per-peer round-robin with newcomers first, quarantine."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import pytest

from mrosd import backports
from mrosd.errors import MrosError
from mrosd.web.probes import Attempt, ProbePool


class Jobs:
    """Probe jobs that hang until released (or forever), recording what started and what failed."""

    def __init__(self) -> None:
        self.started: list[str] = []
        self.failed: dict[str, str] = {}
        self.release = asyncio.Event()

    def job(
        self, key: str, *, hang: bool = False, address: str = ""
    ) -> tuple[Callable[[Attempt], Awaitable[None]], Callable[[str], None]]:
        async def run(attempt: Attempt) -> None:
            if address:
                attempt.contact(address)
            self.started.append(key)
            if hang:
                await asyncio.Event().wait()
            await self.release.wait()

        def fail(reason: str) -> None:
            self.failed[key] = reason

        return run, fail


async def test_one_peer_cannot_fill_the_pool_and_a_newcomer_goes_first() -> None:
    pool = ProbePool(max_total=4, per_peer=2, timeout=5.0)
    jobs = Jobs()
    for i in range(100):
        pool.submit("/rogue", f"rogue {i}", *jobs.job(f"rogue {i}", hang=True))
    for i in range(3):
        pool.submit(f"/old{i}", f"old {i}", *jobs.job(f"old {i}"))
    await asyncio.sleep(0)
    assert len(pool.in_flight()) == 4
    assert sum(k.startswith("rogue") for k in pool.in_flight()) == 2  # its share, no more
    pool.submit("/new", "new", *jobs.job("new"))
    jobs.release.set()
    async with backports.timeout(2):
        while "new" not in jobs.started:  # noqa: ASYNC110 - the pool runs the job in its own task
            await asyncio.sleep(0)
    assert jobs.started.index("new") < jobs.started.index("old 2")  # ahead of peers that waited longer
    await pool.aclose()


async def test_a_peer_that_times_out_is_quarantined_with_its_address() -> None:
    pool = ProbePool(max_total=8, per_peer=1, timeout=0.05, quarantine=60.0)
    jobs = Jobs()
    for i in range(5):
        pool.submit("/rogue", f"rogue {i}", *jobs.job(f"rogue {i}", hang=True, address="10.0.0.1:9"))
    async with backports.timeout(2):
        while len(jobs.failed) < 5:  # noqa: ASYNC110 - failures arrive through the pool's callbacks
            await asyncio.sleep(0.01)
    assert jobs.started == ["rogue 0"]  # one timed out; the rest failed without a connection
    assert "did not answer" in jobs.failed["rogue 4"]
    # Another name at the same address fails without a connection, and so does a lookup for the rogue.
    pool.submit("/rogue2", "other", *jobs.job("other", address="10.0.0.1:9"))
    async with backports.timeout(2):
        while "other" not in jobs.failed:  # noqa: ASYNC110
            await asyncio.sleep(0.01)
    with pytest.raises(MrosError, match="not probed again"):
        await pool.lookup("/rogue", lambda attempt: asyncio.sleep(0))
    await pool.aclose()


async def test_a_lookup_never_waits_behind_background_probes() -> None:
    pool = ProbePool(max_total=2, per_peer=2, timeout=5.0, lookup_timeout=0.1)
    jobs = Jobs()
    for i in range(10):
        pool.submit("/busy", f"busy {i}", *jobs.job(f"busy {i}", hang=True))

    async def answer(attempt: Attempt) -> str:
        return "std_srvs/Trigger"

    async with backports.timeout(1):
        assert await pool.lookup("/honest", answer) == "std_srvs/Trigger"

    async def silent(attempt: Attempt) -> str:
        await asyncio.Event().wait()
        return ""

    with pytest.raises(TimeoutError, match="did not answer"):
        await pool.lookup("/silent", silent)
    await pool.aclose()
