"""Shared-memory transport fixtures: publisher/subscriber processes and a scan for rings left anywhere."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from tests.rosenv import Processes

NODE = str(Path(__file__).with_name("shmnode.py"))


@pytest.fixture(autouse=True)
def shared_memory_on(monkeypatch: pytest.MonkeyPatch) -> None:
    """On by default; set here so that ``MROSD_SHM=0`` in a developer's environment does not turn these tests off."""
    monkeypatch.setenv("MROSD_SHM", "1")


def held_rings(pids: set[int] | None = None) -> dict[int, int]:
    """pid -> number of descriptors and mappings of ``mrosd-shm-`` rings (every process, or ``pids``)."""
    found: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or (pids is not None and int(entry) not in pids):
            continue
        try:
            n = sum(kind.startswith("/memfd:mrosd-shm-") for kind in fd_kinds(int(entry)))
            with open(f"/proc/{entry}/maps") as f:
                n += sum(1 for line in f if "/memfd:mrosd-shm-" in line)
        except OSError:
            continue
        if n:
            found[int(entry)] = n
    return found


def fd_kinds(pid: int) -> list[str]:
    out = []
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            out.append(os.readlink(f"/proc/{pid}/fd/{fd}"))
        except OSError:
            pass
    return out


_buffers: dict[int, bytearray] = {}


def read_line(proc: subprocess.Popen[bytes], prefix: str, timeout: float = 20.0) -> str:
    """The first stdout line starting with ``prefix`` (bounded); fails with stderr if the process dies.

    Reads the pipe with os.read into our own buffer: a buffered ``readline`` would hide a second line that
    arrived with the first from ``select``.
    """
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    buf = _buffers.setdefault(proc.pid, bytearray())
    deadline = time.monotonic() + timeout
    while True:
        while b"\n" in buf:
            end = buf.index(b"\n")
            line = buf[:end].decode().strip()
            del buf[: end + 1]
            if line.startswith(prefix):
                return line[len(prefix) :].strip()
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no {prefix!r} line within {timeout} s")
        ready, _, _ = select.select([fd], [], [], left)
        if not ready:
            continue
        chunk = os.read(fd, 65536)
        if not chunk:
            proc.wait(5)
            err = proc.stderr.read().decode() if proc.stderr else ""
            raise AssertionError(f"process exited ({proc.returncode}) before {prefix!r}: {err[-2000:]}")
        buf += chunk


def start_pub(procs: Processes, *args: str) -> tuple[subprocess.Popen[bytes], str, str]:
    proc = procs.start([sys.executable, NODE, "pub", *args], stdin=subprocess.PIPE)
    address, token = read_line(proc, "addr").split()
    return proc, address, token


def start_sub(procs: Processes, address: str, token: str, *args: str, hold: bool = False) -> subprocess.Popen[bytes]:
    """A subscriber; with ``hold`` it stays attached after its result until ``command(proc, "")``."""
    stdin = subprocess.PIPE if hold else subprocess.DEVNULL
    proc = procs.start([sys.executable, NODE, "sub", address, token, *args], stdin=stdin)
    read_line(proc, "attached")
    return proc


def command(proc: subprocess.Popen[bytes], line: str) -> None:
    assert proc.stdin is not None
    proc.stdin.write(line.encode() + b"\n")
    proc.stdin.flush()


def result(proc: subprocess.Popen[bytes]) -> dict[str, Any]:
    got: dict[str, Any] = json.loads(read_line(proc, "result", timeout=60))
    return got
