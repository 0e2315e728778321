"""IXM integration fixtures: a real daemon process, and a guard that no segment outlives its holders.

Segments are memfds: they have no name in /dev/shm, but every process holding one shows it in
/proc/PID/fd as ``/memfd:<segment_prefix><n> (deleted)``.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from mrosd.ixm.resources import held_memfds
from mrosd.ixm.server import SHM_PREFIX, segment_prefix
from tests.rosenv import Processes

SHM = Path("/dev/shm")


def ixm_segments() -> set[str]:
    """Names of the IXM segments some process on the machine holds open."""
    return held_memfds(SHM_PREFIX)


def own_segments(socket_path: str) -> set[str]:
    """The segments of the daemon serving ``socket_path`` (others may run at the same time)."""
    prefix = segment_prefix(socket_path)
    return {n for n in ixm_segments() if n.startswith(prefix)}


def wait_line(proc: subprocess.Popen[bytes], expected: str, timeout: float = 10.0) -> None:
    """Read stdout lines until ``expected`` (bounded); fail with stderr if the process dies first."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            break
        line = proc.stdout.readline().decode().strip()
        if line == expected:
            return
        if not line and proc.poll() is not None:
            err = proc.stderr.read().decode() if proc.stderr else ""
            raise AssertionError(f"process exited ({proc.returncode}) before {expected!r}: {err}")
    raise AssertionError(f"no {expected!r} line within {timeout} s")


def start_daemon(procs: Processes, socket_path: str, config: str | None = None) -> subprocess.Popen[bytes]:
    argv = ["-m", "mrosd.ixm", "--socket", socket_path, "--log-level", "debug"]
    if config:
        argv += ["--config", config]
    proc = procs.our_python(argv, stderr=subprocess.DEVNULL)
    wait_line(proc, "ready")
    return proc


class ShmGuard:
    """The socket paths whose daemons' segments must all be gone when the test ends.

    Segment names carry a hash of their daemon's socket path, so a test checks only its own daemons and
    is not confused by other daemons running on the machine at the same time (benchmarks, other suites).
    """

    def __init__(self) -> None:
        self.prefixes: set[str] = set()

    def watch(self, socket_path: str) -> str:
        self.prefixes.add(segment_prefix(socket_path))
        return socket_path

    def leftovers(self) -> set[str]:
        return {n for n in ixm_segments() if n.startswith(tuple(self.prefixes))}


@pytest.fixture
def shm_guard(tmp_path: Path) -> Iterator[ShmGuard]:
    """Fails the test if a segment of its daemons is still held when it ends (checked after they stopped).

    ``tmp_path / "ixm.sock"`` is watched by default; call ``watch(path)`` for other socket paths.
    """
    guard = ShmGuard()
    guard.watch(str(tmp_path / "ixm.sock"))
    yield guard
    leaked = guard.leftovers()
    assert not leaked, f"leaked shared memory segments: {sorted(leaked)}"
    assert not {n for n in os.listdir(SHM) if n.startswith("mrosd-ixm-")}, "an IXM segment has a name in /dev/shm"


@pytest.fixture
def ixm_socket(shm_guard: ShmGuard, tmp_path: Path) -> Iterator[str]:
    """Socket path of a running ``python -m mrosd.ixm`` daemon (stopped, and its segments checked, at the end)."""
    procs = Processes(tmp_path)
    path = str(tmp_path / "ixm.sock")
    try:
        start_daemon(procs, path)
        yield path
    finally:
        procs.close()


def until(condition: Callable[[], bool], timeout: float = 10.0) -> None:
    """Re-check ``condition`` (each check is a round trip to the daemon) until true, bounded by ``timeout``."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"condition not met within {timeout} s")
        time.sleep(0.005)


def python_child(procs: Processes, code: str) -> subprocess.Popen[bytes]:
    """Run ``code`` in a fresh interpreter of ours (a separate process for the other side of a key)."""
    return procs.start([sys.executable, "-c", code], stdin=subprocess.PIPE)
