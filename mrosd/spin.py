"""Adaptive spin-then-block: stay awake for a short, self-tuning window before going to sleep.

Why: on a virtual machine without guest halt-polling (``/sys/module/haltpoll/parameters/guest_halt_poll_ns``
= 0, as here) a CPU that goes idle halts, and waking the process that sleeps on it takes an inter-processor
interrupt through the hypervisor: 50 us to several ms. For a request/answer exchange (a TCPROS ping/pong, a
service call, an IXM write and its acknowledgement) that wake-up, paid on every hop, is most of the latency.
Spinning a little before sleeping keeps the CPU out of halt when the answer is about to arrive.

The window adapts as the kernel's haltpoll governor does, so that spinning costs CPU only where it pays:

- an event that arrives while spinning is a hit (the window stays);
- an event that arrives ``gap`` after the spin ended, with ``gap <= max``, would have been caught by a
  longer spin: the window doubles (starting at ``max / 4``, at most ``max``);
- an event that arrives later than ``max`` after the spin ended could not have been caught: the window
  halves, and below ``max / 4`` it is 0, so periodic or sparse traffic (a 100 Hz sensor, a 1 kHz timer) does
  not spin at all after a few events.

So the CPU spent spinning is at most ``max`` per event, and only while events come less than ``max`` apart.
A process allowed on a single CPU never spins (it would only take the CPU its peer needs). A spin step that
finds the event loop idle calls ``sched_yield``, so a peer waiting for this CPU runs at once (yielding in
busy steps too was measured and cost a third of the small-message throughput).

Spinning pays only when CPUs would otherwise sit idle: beside a CPU-bound process a TCPROS ping/pong measured
70-124 us medians spinning against 42-75 us with ``MROSD_SPIN_US=0``, and on a host whose CPUs were
contended (PSI ``some avg10`` above 90 %) 300 us against 40 us. So no spin starts while the kernel's CPU
pressure (``/proc/pressure/cpu``, ``some avg10``: the share of time runnable tasks waited for a CPU) is above
``PRESSURE_LIMIT`` percent; it is read at most once a second. A detector that stopped spinning when a spin
step was preempted was tried and dropped: on an idle 2-core machine the two spinning peers are preempted by
incidental tasks often enough that it undid most of the gain (PSI, averaged over 10 s, does not flicker so).
``MROSD_SPIN_US=0`` turns spinning off for good.

Periodic traffic is different: a camera at 30 Hz or a 50 Hz topic arrives far beyond ``max`` after the last
event, so the window above is 0, and each message pays the halted CPU's wake-up (on this VM 110-130 us of a
loaned message's 250). ``Anticipation`` (pure) learns a source's period and jitter; once they are steady it
names a window around the next expected arrival, and ``LoopSpinner.anticipate`` spins the loop through it.
The window opens ``LEAD_NS`` early (event loop timers have millisecond resolution) and costs at most ``DUTY``
of the period (at 50 Hz, 2 ms in 20; a period too short or too irregular for that gets no window). The
message's arrival ends the spin at once (the reactive window, 0 for such traffic), as does the window's end.

``MROSD_SPIN_US`` sets ``max`` in microseconds (default 200, as the kernel's ``guest_halt_poll_ns``); 0 turns
spinning off. ``AdaptiveSpin`` is the pure policy; ``LoopSpinner`` keeps an asyncio event loop polling
(``epoll`` with a zero timeout) for the window after each ``poke()``; the IXM sync ``wait`` spins on the
shared-memory sequence counter itself.
"""

from __future__ import annotations

import asyncio
import os
import time
import weakref
from collections.abc import Callable

__all__ = [
    "DEFAULT_SPIN_US",
    "PRESSURE_LIMIT",
    "AdaptiveSpin",
    "Anticipation",
    "LoopSpinner",
    "cpu_pressure",
    "default_max_ns",
    "loop_spinner",
]

#: Default upper bound of the spin window, in microseconds.
DEFAULT_SPIN_US = 200

_now = time.monotonic_ns

#: A spin step that took less than this found the event loop idle (an empty poll and our own task step).
_IDLE_STEP_NS = 20_000

#: No spin starts while the CPU pressure (PSI ``some avg10``, percent) is above this.
PRESSURE_LIMIT = 20.0
#: How often the pressure is read again.
_PRESSURE_EVERY_NS = 1_000_000_000
_PRESSURE_FILE = "/proc/pressure/cpu"


def cpu_pressure() -> float | None:
    """The kernel's CPU pressure, ``some avg10`` in percent; None where PSI is not available."""
    try:
        with open(_PRESSURE_FILE, "rb") as f:
            first = f.readline()
    except OSError:
        return None
    for field in first.split():
        if field.startswith(b"avg10="):
            try:
                return float(field[6:])
            except ValueError:
                return None
    return None


def default_max_ns(environ: dict[str, str] | None = None) -> int:
    """The spin bound in ns: ``MROSD_SPIN_US`` (default 200 us); 0 when this process may use only one CPU.

    Raises:
        ValueError: ``MROSD_SPIN_US`` is not a non-negative integer.
    """
    env = os.environ if environ is None else environ
    raw = env.get("MROSD_SPIN_US", "").strip()
    if raw:
        try:
            us = int(raw)
        except ValueError:
            raise ValueError(f"MROSD_SPIN_US must be a whole number of microseconds, got {raw!r}") from None
        if us < 0:
            raise ValueError(f"MROSD_SPIN_US must not be negative, got {us}")
    else:
        us = DEFAULT_SPIN_US
    try:
        if len(os.sched_getaffinity(0)) < 2:
            return 0  # a spinning process would only take the CPU its peer needs
    except (AttributeError, OSError):
        pass
    return us * 1000


class AdaptiveSpin:
    """The window policy (pure): how long to spin before blocking, tuned by how long blocking lasted.

    Args:
        max_ns: upper bound of the window; 0 never spins.
    """

    __slots__ = ("max_ns", "start_ns", "window_ns")

    def __init__(self, max_ns: int) -> None:
        self.max_ns = max(0, max_ns)
        self.start_ns = self.max_ns // 4
        #: The current window: spin this long before blocking.
        self.window_ns = 0

    def blocked(self, gap_ns: int) -> None:
        """The event came ``gap_ns`` after the spin ended (the time spent blocked): adapt the window."""
        if gap_ns <= self.max_ns:
            self.window_ns = min(self.max_ns, max(self.start_ns, self.window_ns * 2))
        else:
            window = self.window_ns // 2
            self.window_ns = window if window >= self.start_ns else 0


#: An anticipation window opens this long before the expected arrival: event loop timers fire with
#: millisecond resolution (uvloop rounds to the nearest ms, asyncio's selector waits whole ms).
LEAD_NS = 1_000_000
#: ... and stays open at least this long after it.
AFTER_NS = 300_000
#: The most of a period that anticipation may spin.
DUTY = 0.10
#: Periods anticipated: below this the loop is busy anyway; above it a 10 % spin is long and rarely useful.
MIN_PERIOD_NS = 2_000_000
MAX_PERIOD_NS = 1_000_000_000
#: Steady intervals needed before the first window (and again after a change of rhythm).
STEADY = 4


class Anticipation:
    """The expected time of a periodic source's next event, and a window to spin through around it (pure).

    The period is a running mean of the intervals (1/8 weight), the jitter a running mean of each
    interval's distance from it (1/4 weight). An interval more than a quarter off the period (a lost
    message, a new rate) restarts the count: no window until ``STEADY`` steady intervals again.
    """

    __slots__ = ("jitter_ns", "last_ns", "period_ns", "steady")

    def __init__(self) -> None:
        self.last_ns = 0
        self.period_ns = 0
        self.jitter_ns = 0
        self.steady = 0

    def arrived(self, now_ns: int) -> tuple[int, int] | None:
        """An event at ``now_ns``: the window (start, end) in which to spin for the next, or None."""
        last, self.last_ns = self.last_ns, now_ns
        if not last:
            return None
        interval = now_ns - last
        period = self.period_ns
        error = interval - period
        if not period or abs(error) * 4 > period:
            self.period_ns, self.jitter_ns, self.steady = interval, 0, 0
            return None
        self.period_ns = period = period + error // 8
        self.jitter_ns += (abs(error) - self.jitter_ns) // 4
        self.steady += 1
        if self.steady < STEADY or not MIN_PERIOD_NS <= period <= MAX_PERIOD_NS:
            return None
        before = LEAD_NS + 2 * self.jitter_ns
        after = max(AFTER_NS, 2 * self.jitter_ns)
        if before + after > period * DUTY:
            return None
        expected = now_ns + period
        return expected - before, expected + after


class LoopSpinner:
    """Keeps one event loop polling for the adaptive window after each ``poke()`` (an I/O event).

    While spinning, a task repeats ``await asyncio.sleep(0)``: the loop then polls its selector with a zero
    timeout instead of sleeping, so a socket becoming readable is seen at once. Works
    with any event loop (asyncio's or uvloop). ``poke`` is cheap (a clock read and a comparison).
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        max_ns: int | None = None,
        pressure: Callable[[], float | None] = cpu_pressure,
    ) -> None:
        self._loop = loop
        self.policy = AdaptiveSpin(default_max_ns() if max_ns is None else max_ns)
        self._until = 0
        self._task: asyncio.Task[None] | None = None
        self._pressure = pressure
        self._pressure_at = -_PRESSURE_EVERY_NS
        self._contended = False
        #: Spins started and events that arrived while spinning (for tests and statistics).
        self.spins = 0
        self.hits = 0
        #: Anticipation windows opened (``anticipate``), and the probes of the open ones: (end, probe)
        self.anticipated = 0
        self._probes: list[tuple[int, Callable[[], bool]]] = []

    def poke(self) -> None:
        """Note an I/O event now: extend the spin, or adapt and start one."""
        policy = self.policy
        if not policy.max_ns:
            return
        now = _now()
        if self._task is not None:
            self.hits += 1
        else:
            policy.blocked(now - self._until)
            if now - self._pressure_at >= _PRESSURE_EVERY_NS:
                self._pressure_at = now
                value = self._pressure()
                self._contended = value is not None and value > PRESSURE_LIMIT
            if policy.window_ns and not self._contended and not self._loop.is_closed():
                self.spins += 1
                self._task = self._loop.create_task(self._spin())
        self._until = now + policy.window_ns

    def anticipate(
        self, window: tuple[int, int], probe: Callable[[], bool] | None = None
    ) -> asyncio.TimerHandle | None:
        """Spin through ``window`` (monotonic ns, from ``Anticipation.arrived``): a timer opens it. Returns
        the timer, for the caller to cancel when the source's next event comes first or it closes; None
        when spinning is off or the CPUs are contended.

        ``probe``, called at each spin step inside the window until it returns True, may see the event
        itself before its wake-up does (a shared-memory subscriber reads the ring's head: the message is
        there before the publisher's ``send`` returns, and before the loop would dispatch the wake-up).
        """
        if not self.policy.max_ns or self._contended or self._loop.is_closed():
            return None
        start, end = window
        return self._loop.call_later(max(0, start - _now()) / 1e9, self._open, end, probe)

    def _open(self, end_ns: int, probe: Callable[[], bool] | None = None) -> None:
        if self._contended:
            return
        self.anticipated += 1
        self._until = max(self._until, end_ns)
        if probe is not None:
            self._probes.append((end_ns, probe))
        if self._task is None and not self._loop.is_closed():
            self.spins += 1
            self._task = self._loop.create_task(self._spin())

    def _run_probes(self, now: int) -> None:
        probes = self._probes
        for i in range(len(probes) - 1, -1, -1):
            end, probe = probes[i]
            if now >= end:
                del probes[i]
                continue
            try:
                done = probe()
            except Exception:  # a probe is the caller's: its failure ends it, not the spin
                done = True
            if done:
                del probes[i]

    async def _spin(self) -> None:
        try:
            last = _now()
            while last < self._until:
                await asyncio.sleep(0)
                now = _now()
                if self._probes:
                    self._run_probes(now)
                if now - last < _IDLE_STEP_NS:
                    # the loop had nothing else to run: let a peer that waits for this CPU have it now
                    os.sched_yield()
                last = now
        finally:
            self._task = None
            self._until = min(self._until, _now())
            self._probes.clear()


_spinners: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, LoopSpinner] = weakref.WeakKeyDictionary()


def loop_spinner(loop: asyncio.AbstractEventLoop | None = None) -> LoopSpinner:
    """The one ``LoopSpinner`` of ``loop`` (default: the running loop), shared by every node and key on it."""
    if loop is None:
        loop = asyncio.get_running_loop()
    spinner = _spinners.get(loop)
    if spinner is None:
        spinner = _spinners[loop] = LoopSpinner(loop)
    return spinner
