"""``CoalescedWriter``: what one loop turn queued leaves in order, in the foreground or from its writer thread.

The background mode (``mros topic echo``) writes from a thread straight to the file descriptor, so these
tests check it keeps the order of pieces across turns, hands long pieces over without joining them, waits in
``close()`` until everything is written, and reports a reader that went away (quietly) apart from a write
that failed (``error``), through ``on_broken`` called in the loop's thread.
"""

from __future__ import annotations

import asyncio
import io
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import pytest
from mros_cli import writer as writer_module
from mros_cli.writer import CoalescedWriter

from mrosd import backports


def _reader(fd: int, into: bytearray) -> threading.Thread:
    def drain() -> None:
        while chunk := os.read(fd, 1 << 16):
            into.extend(chunk)
        os.close(fd)

    thread = threading.Thread(target=drain, daemon=True)
    thread.start()
    return thread


@pytest.fixture
def pipe() -> Iterator[tuple[int, BinaryIO]]:
    """A pipe: its read end's fd, and its write end as a file object (closed at teardown)."""
    r, w = os.pipe()
    with open(w, "wb") as out:
        yield r, out


@pytest.fixture
def full() -> Iterator[BinaryIO]:
    """/dev/full, unbuffered (nothing is left in a buffer to fail again at close)."""
    if not Path("/dev/full").exists():
        pytest.skip("needs /dev/full")
    with open("/dev/full", "wb", buffering=0) as out:
        yield out


def _turns() -> list[list[bytes | bytearray]]:
    """Loop turns of pieces: small ones (joined when many), long ones (kept), and a mixed burst."""
    small = [f"msg {i}\n---\n".encode() for i in range(300)]
    long = [bytearray(os.urandom(3 * writer_module._JOIN_BELOW)) for _ in range(4)]
    mixed: list[bytes | bytearray] = [b"data: ", long[0], b"\n---\n"] * 30
    return [small[:10], small, long, mixed, [b"end\n"]]


@pytest.mark.parametrize("background", [False, True])
async def test_every_piece_arrives_in_order_across_loop_turns(pipe: tuple[int, BinaryIO], background: bool) -> None:
    r, out = pipe
    got = bytearray()
    reader = _reader(r, got)
    writer = CoalescedWriter(out, background=background)
    expected = bytearray()
    for turn in _turns():
        writer.add(turn)
        expected.extend(b"".join(turn))
        await asyncio.sleep(0)  # the turn ends: its flush runs
    writer.close()
    out.close()
    reader.join(timeout=30)
    assert got == expected
    assert not writer.broken


def test_short_pieces_are_joined_and_long_ones_kept_as_they_are() -> None:
    long = bytearray(writer_module._JOIN_BELOW)
    few: list[bytes | bytearray] = [b"a", long, b"b"]
    assert writer_module._coalesce(few) is few  # a handful of pieces goes to writelines/writev as it is
    many: list[bytes | bytearray] = [b"x"] * 40 + [long] + [b"y"] * 40
    joined = writer_module._coalesce(many)
    assert joined == [b"x" * 40, long, b"y" * 40]
    assert joined[1] is long


async def test_a_closed_pipe_breaks_the_background_writer_quietly_and_calls_on_broken_in_the_loop(
    pipe: tuple[int, BinaryIO],
) -> None:
    r, out = pipe
    os.close(r)
    called: list[threading.Thread] = []
    gone = asyncio.Event()

    def on_broken() -> None:
        called.append(threading.current_thread())
        gone.set()

    writer = CoalescedWriter(out, on_broken=on_broken, background=True)
    writer.add([b"nobody reads this\n"])
    await backports.wait_for(gone.wait(), timeout=30)
    writer.add([b"dropped\n"])  # after the break: ignored, never blocks
    writer.close()
    assert writer.broken
    assert writer.error is None
    assert called == [threading.main_thread()]


@pytest.mark.parametrize("background", [False, True])
async def test_a_failing_write_is_reported_as_the_error(full: BinaryIO, background: bool) -> None:
    gone = asyncio.Event()
    writer = CoalescedWriter(full, on_broken=gone.set, background=background)
    writer.add([b"x" * 100])
    await backports.wait_for(gone.wait(), timeout=30)
    writer.close()
    assert writer.broken
    assert isinstance(writer.error, OSError)


async def test_without_a_file_descriptor_the_writer_stays_in_the_foreground() -> None:
    out = io.BytesIO()
    writer = CoalescedWriter(out, background=True)
    writer.add([b"a", b"b"])
    await asyncio.sleep(0)
    assert out.getvalue() == b"ab"  # written by the loop turn's flush itself
    writer.close()
