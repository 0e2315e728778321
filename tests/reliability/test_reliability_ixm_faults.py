"""IXM under faults: a writer SIGKILLed while copying a value (readers keep the last complete one), and the
daemon SIGKILLed and restarted."""

from __future__ import annotations

import os
import random
import signal
import struct
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from mrosd.errors import IxmError
from mrosd.ixm.client import IxmClient
from mrosd.ixm.server import segment_prefix
from tests.integration.ixm.conftest import ixm_segments as all_segments
from tests.reliability.relnodes import kill9
from tests.rosenv import Processes, iter_lines_until

SIZE = 8 << 20  # 8 MiB: copying it takes milliseconds, so a random kill often lands inside the copy
WORD = struct.Struct("<Q")


def ixm_segments(prefix: str = "mrosd-ixm-") -> set[str]:
    """Segments (memfds) held by any process; pass the test daemon's ``segment_prefix`` to ignore others."""
    return {n for n in all_segments() if n.startswith(prefix)}


def start_daemon(procs: Processes, path: str) -> subprocess.Popen[bytes]:
    proc = procs.our_python(["-m", "mrosd.ixm", "--socket", path], stderr=subprocess.DEVNULL)
    assert next(iter_lines_until(proc, 1, 20.0)) == "ready"
    return proc


@pytest.fixture
def no_new_segments(tmp_path: Path) -> Iterator[None]:
    """Fails the test if a segment of its own daemon (socket ``tmp_path/ixm.sock``) is still held at the end."""
    prefix = segment_prefix(str(tmp_path / "ixm.sock"))
    yield
    assert ixm_segments(prefix) == set(), "shared memory segments still held"


WRITER = textwrap.dedent(
    """
    import struct, sys
    from mrosd.ixm.client import IxmClient
    c = IxmClient(sys.argv[1], name="writer")
    k = c.open("/big", "uint8", count=int(sys.argv[2]), mode="w")
    i = int(sys.argv[3])
    k.write_bytes(struct.pack("<Q", i) * (int(sys.argv[2]) // 8))
    print("ready", flush=True)
    while True:
        i += 1
        k.write_bytes(struct.pack("<Q", i) * (int(sys.argv[2]) // 8))
    """
)


def consistent(buf: bytearray) -> int:
    """The value's counter, after checking every word carries the same one (a torn copy would mix two)."""
    first = WORD.unpack_from(buf, 0)[0]
    assert buf == WORD.pack(first) * (len(buf) // 8), "torn value: words of two different writes"
    return int(first)


def test_a_writer_killed_while_writing_leaves_readers_the_last_complete_value_at_once_and_the_next_writer_recovers(
    no_new_segments: None, procs: Processes, tmp_path: Path
) -> None:
    path = str(tmp_path / "ixm.sock")
    start_daemon(procs, path)
    buf = bytearray(SIZE)
    mid_copy = 0
    with IxmClient(path, name="reader") as ixm:
        key = ixm.open("/big", "uint8", count=SIZE, mode="r")
        base = 0
        for _ in range(4):
            writer = procs.our_python(["-c", WRITER, path, str(SIZE), str(base)])
            assert next(iter_lines_until(writer, 1, 20.0)) == "ready"
            time.sleep(random.uniform(0.0, 0.05))
            kill9(writer)
            mid_copy += key.seq & 1  # odd: the kill landed inside a copy
            # no error, no wait: the active slot still holds the last complete value, whole
            published = key.seq & ~1
            assert key.read_into(buf) == SIZE
            assert consistent(buf) >= base
            assert key.seq & ~1 == published
            base += 1_000_000
        # a writer killed inside a copy, deterministically: the counter stays odd, readers get the value before
        writer = procs.our_python(["-c", WRITER, path, str(SIZE), str(base)])
        assert next(iter_lines_until(writer, 1, 20.0)) == "ready"
        deadline = time.monotonic() + 10.0
        while not key.seq & 1:  # each 8 MiB copy takes milliseconds: catch the writer inside one
            assert time.monotonic() < deadline, "never saw the writer mid-copy"
        os.killpg(writer.pid, signal.SIGSTOP)
        if key.seq & 1:  # stopped inside the copy (not just after it): kill it there
            mid_copy += 1
        kill9(writer)
        assert key.read_into(buf) == SIZE  # at once: no error and no give-up timeout, as before double buffering
        assert consistent(buf) >= base
        # a new writer recovers the key whatever state the last one left it in
        base += 1_000_000
        writer = procs.our_python(["-c", WRITER, path, str(SIZE), str(base)])
        assert next(iter_lines_until(writer, 1, 20.0)) == "ready"
        kill9(writer)
        assert key.read_into(buf) == SIZE
        assert consistent(buf) >= base
        key.close()
    assert mid_copy >= 1, "no kill landed inside a copy: the test did not exercise the fault"
    print("writer kills that landed inside a copy:", mid_copy, file=sys.stderr)


def test_a_daemon_killed_with_sigkill_gives_clients_a_clear_error_and_they_reopen_after_restart(
    no_new_segments: None, procs: Processes, tmp_path: Path
) -> None:
    path = str(tmp_path / "ixm.sock")
    daemon = start_daemon(procs, path)
    before = ixm_segments(segment_prefix(path))
    old = IxmClient(path, name="survivor")
    key = old.open("/pose", "float64", count=3, mode="rw")
    key.write([1.0, 2.0, 3.0])
    assert len(ixm_segments(segment_prefix(path)) - before) == 1

    kill9(daemon)
    # the mapping a client already holds stays valid memory (no crash, no SIGBUS)
    assert list(key.read()) == [1.0, 2.0, 3.0]
    with pytest.raises(IxmError) as excinfo:
        old.open("/other", "int32", mode="w")
    assert path in str(excinfo.value) or "daemon" in str(excinfo.value)
    with pytest.raises(IxmError, match="cannot reach the IXM daemon"):
        IxmClient(path, timeout=2)
    old.close()
    # the daemon's memfd went with it, the client's with its close: nothing left for a restart to sweep
    assert ixm_segments(segment_prefix(path)) - before == set(), "the crashed run's segment is still held"

    start_daemon(procs, path)
    with IxmClient(path, name="again") as again:
        fresh = again.open("/pose", "float64", count=3, mode="rw")
        fresh.write([4.0, 5.0, 6.0])
        assert list(fresh.read()) == [4.0, 5.0, 6.0]
        fresh.close()
