"""mrosd.spin: the adaptive spin window (pure policy) and the event-loop spinner on a real loop."""

from __future__ import annotations

import asyncio
import os
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd import backports, spin
from mrosd.spin import (
    AFTER_NS,
    DEFAULT_SPIN_US,
    DUTY,
    LEAD_NS,
    MAX_PERIOD_NS,
    MIN_PERIOD_NS,
    STEADY,
    AdaptiveSpin,
    Anticipation,
    LoopSpinner,
    cpu_pressure,
    default_max_ns,
    loop_spinner,
)

MAX = 200_000


def test_the_window_starts_closed_and_opens_when_an_event_came_soon_after_blocking() -> None:
    spin = AdaptiveSpin(MAX)
    assert spin.window_ns == 0
    spin.blocked(150_000)  # a longer spin would have caught it
    assert spin.window_ns == MAX // 4
    spin.blocked(10_000)
    assert spin.window_ns == MAX // 2
    spin.blocked(10_000)
    spin.blocked(10_000)
    assert spin.window_ns == MAX  # capped


def test_the_window_halves_then_closes_when_events_come_later_than_the_bound() -> None:
    spin = AdaptiveSpin(MAX)
    for _ in range(3):
        spin.blocked(0)
    assert spin.window_ns == MAX
    spin.blocked(MAX + 1)
    assert spin.window_ns == MAX // 2
    spin.blocked(10 * MAX)
    assert spin.window_ns == MAX // 4
    spin.blocked(10 * MAX)
    assert spin.window_ns == 0  # a 1 kHz timer or a 100 Hz sensor does not spin at all
    spin.blocked(10 * MAX)
    assert spin.window_ns == 0


@given(st.lists(st.integers(min_value=0, max_value=10**9), max_size=50), st.integers(0, 10**6))
def test_the_window_never_exceeds_the_bound_and_is_zero_or_at_least_a_quarter(gaps: list[int], bound: int) -> None:
    spin = AdaptiveSpin(bound)
    for gap in gaps:
        spin.blocked(gap)
        assert 0 <= spin.window_ns <= bound
        assert spin.window_ns == 0 or spin.window_ns >= bound // 4


def test_a_zero_bound_never_spins() -> None:
    spin = AdaptiveSpin(0)
    for _ in range(5):
        spin.blocked(0)
    assert spin.window_ns == 0


def test_the_bound_comes_from_mrosd_spin_us(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert default_max_ns({}) == DEFAULT_SPIN_US * 1000
    assert default_max_ns({"MROSD_SPIN_US": "50"}) == 50_000
    assert default_max_ns({"MROSD_SPIN_US": "0"}) == 0
    with pytest.raises(ValueError, match="MROSD_SPIN_US must be a whole number"):
        default_max_ns({"MROSD_SPIN_US": "fast"})
    with pytest.raises(ValueError, match="must not be negative"):
        default_max_ns({"MROSD_SPIN_US": "-5"})


def test_a_process_confined_to_one_cpu_never_spins(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})
    assert default_max_ns({"MROSD_SPIN_US": "500"}) == 0


def no_pressure() -> float:
    return 0.0


async def wait_idle(spinner: LoopSpinner, timeout: float = 5.0) -> None:
    if spinner._task is not None:
        await backports.wait_for(spinner._task, timeout)  # the spin ends by itself at the window's end


async def test_the_loop_spinner_spins_after_close_events_and_stops_by_itself() -> None:
    # 50 ms: far above scheduling noise
    spinner = LoopSpinner(asyncio.get_running_loop(), max_ns=50_000_000, pressure=no_pressure)
    spinner.poke()  # first event ever: nothing to learn from, no spin
    assert spinner._task is None
    spinner.poke()  # a second event right after: the window opens and the loop spins
    assert spinner.spins == 1 and spinner._task is not None
    spinner.poke()  # an event while spinning is a hit and extends the spin
    assert spinner.hits == 1
    await wait_idle(spinner)  # the window ends without any further event
    assert spinner.policy.window_ns == 50_000_000 // 4


async def test_the_loop_spinner_stays_asleep_for_sparse_events() -> None:
    spinner = LoopSpinner(asyncio.get_running_loop(), max_ns=1_000_000, pressure=no_pressure)  # 1 ms
    spinner.poke()
    spinner.poke()
    await wait_idle(spinner)
    for _ in range(3):  # events 20 ms apart: the window halves, then closes
        await asyncio.sleep(0.02)
        spinner.poke()
        await wait_idle(spinner)
    assert spinner.policy.window_ns == 0
    spins = spinner.spins
    await asyncio.sleep(0.02)
    spinner.poke()
    assert spinner._task is None and spinner.spins == spins


async def test_a_disabled_spinner_does_nothing() -> None:
    spinner = LoopSpinner(asyncio.get_running_loop(), max_ns=0)
    for _ in range(3):
        spinner.poke()
    assert spinner._task is None and spinner.spins == 0


async def test_one_spinner_per_loop_is_shared() -> None:
    assert loop_spinner() is loop_spinner(asyncio.get_running_loop())


async def test_no_spin_starts_while_the_cpus_are_contended() -> None:
    pressure = [95.0]
    spinner = LoopSpinner(asyncio.get_running_loop(), max_ns=50_000_000, pressure=lambda: pressure[0])
    for _ in range(3):
        spinner.poke()
    assert spinner._task is None and spinner.spins == 0  # the window is open, but nobody waits for nothing
    assert spinner.policy.window_ns > 0
    spinner._pressure_at -= 2_000_000_000  # a second later the pressure is read again, and has gone
    pressure[0] = 0.5
    spinner.poke()
    assert spinner.spins == 1
    await wait_idle(spinner)


def test_cpu_pressure_reads_some_avg10_or_says_unknown(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    psi = tmp_path / "cpu"
    psi.write_text("some avg10=12.34 avg60=1.00 avg300=0.50 total=1\nfull avg10=0.00 avg60=0.00 total=0\n")
    monkeypatch.setattr(spin, "_PRESSURE_FILE", str(psi))
    assert cpu_pressure() == 12.34
    monkeypatch.setattr(spin, "_PRESSURE_FILE", str(tmp_path / "missing"))
    assert cpu_pressure() is None


# --- anticipation of periodic events ------------------------------------------------------------------------

MS = 1_000_000


def feed(rhythm: Anticipation, times: list[int]) -> list[tuple[int, int] | None]:
    return [rhythm.arrived(t) for t in times]


def test_a_steady_period_gets_a_window_around_the_next_event_after_a_few_intervals() -> None:
    rhythm = Anticipation()
    windows = feed(rhythm, [i * 20 * MS for i in range(1, 10)])
    assert windows[: STEADY + 1] == [None] * (STEADY + 1)
    start, end = windows[-1]  # type: ignore[misc]
    expected = 10 * 20 * MS
    assert start == expected - LEAD_NS and end == expected + AFTER_NS
    assert end - start <= 20 * MS * DUTY


@settings(max_examples=200)
@given(st.lists(st.integers(1, 3 * 10**9), min_size=1, max_size=40))
def test_a_window_is_always_ahead_of_the_event_and_within_the_duty(gaps: list[int]) -> None:
    rhythm, now = Anticipation(), 1
    for gap in gaps:
        now += gap
        window = rhythm.arrived(now)
        if window is not None:
            start, end = window
            assert now < start < end
            assert end - start <= rhythm.period_ns * DUTY
            assert MIN_PERIOD_NS <= rhythm.period_ns <= MAX_PERIOD_NS


def test_a_lost_message_or_a_new_rate_restarts_the_count() -> None:
    rhythm = Anticipation()
    times = [i * 20 * MS for i in range(1, 9)]
    assert feed(rhythm, times)[-1] is not None
    assert rhythm.arrived(times[-1] + 40 * MS) is None  # one message lost: twice the period
    assert feed(rhythm, [times[-1] + 40 * MS + i * 20 * MS for i in range(1, STEADY + 1)])[-1] is None
    assert rhythm.arrived(times[-1] + 40 * MS + (STEADY + 1) * 20 * MS) is not None


def test_periods_too_short_too_long_or_too_irregular_get_no_window() -> None:
    for period in (MIN_PERIOD_NS // 2, 2 * MAX_PERIOD_NS):
        assert set(feed(Anticipation(), [i * period for i in range(1, 12)])) == {None}
    # 10 ms +- 1 ms: a window would have to cover more than a tenth of the period
    jittery = [i * 10 * MS + (MS if i % 2 else -MS) for i in range(1, 30)]
    assert set(feed(Anticipation(), jittery)) == {None}


async def test_an_anticipated_window_spins_the_loop_through_it_then_stops() -> None:
    loop = asyncio.get_running_loop()
    spinner = LoopSpinner(loop, max_ns=200_000, pressure=no_pressure)
    now = time.monotonic_ns()
    timer = spinner.anticipate((now + 5 * MS, now + 25 * MS))
    assert timer is not None and spinner.anticipated == 0
    await asyncio.sleep(0.015)
    assert spinner.anticipated == 1 and spinner._task is not None  # inside the window: spinning
    async with backports.timeout(2):
        while spinner._task is not None:  # noqa: ASYNC110 - the spin task ends itself at the window's end
            await asyncio.sleep(0.005)
    assert time.monotonic_ns() >= now + 25 * MS


async def test_no_window_opens_when_spinning_is_off() -> None:
    assert LoopSpinner(asyncio.get_running_loop(), max_ns=0, pressure=no_pressure).anticipate((1, 2)) is None


async def test_a_probe_runs_at_each_spin_step_of_its_window_until_it_says_done() -> None:
    spinner = LoopSpinner(asyncio.get_running_loop(), max_ns=200_000, pressure=no_pressure)
    calls: list[int] = []

    def probe() -> bool:
        calls.append(time.monotonic_ns())
        return len(calls) == 3

    def broken() -> bool:
        raise RuntimeError("the caller's bug")

    now = time.monotonic_ns()
    spinner.anticipate((now + 2 * MS, now + 30 * MS), probe)
    spinner.anticipate((now + 2 * MS, now + 30 * MS), broken)
    async with backports.timeout(2):
        while len(calls) < 3:  # noqa: ASYNC110 - called by the spin task
            await asyncio.sleep(0.001)
    assert min(calls) >= now + 2 * MS  # not before the window opened
    await asyncio.sleep(0.005)
    alive = spinner._task is not None
    assert len(calls) == 3  # done: not called again, though the window lasts
    assert alive or time.monotonic_ns() >= now + 30 * MS  # the task lasts its window (a loaded machine slept past it)
    async with backports.timeout(2):
        while spinner._task is not None:  # noqa: ASYNC110 - ends itself at the window's end
            await asyncio.sleep(0.005)
