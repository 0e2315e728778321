"""SegmentLayout: header round trip, double-buffered seqlock semantics, dead writers, size limits."""

from __future__ import annotations

import contextlib
import threading

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import IxmError
from mrosd.ixm import layout as layout_mod
from mrosd.ixm.layout import HEADER_SIZE, SegmentLayout


def fresh(capacity: int = 64) -> SegmentLayout:
    buf = memoryview(bytearray(SegmentLayout.segment_size(capacity)))
    return SegmentLayout.initialize(buf, type_code=11, capacity=capacity, count=0, type_name="float64")


def test_a_fresh_segment_has_counter_zero_and_an_empty_value() -> None:
    seg = fresh()
    assert seg.seq == 0
    assert seg.read() == (0, b"")
    assert seg.type_code == 11
    assert seg.type_name == "float64"
    assert seg.capacity == 64


def test_each_write_advances_the_counter_by_two_and_is_read_back() -> None:
    seg = fresh()
    assert seg.write(b"abc") == 2
    assert seg.write(b"hello") == 4
    assert seg.read() == (4, b"hello")


@given(st.lists(st.binary(max_size=64), min_size=1, max_size=20))
def test_the_latest_write_is_what_a_reader_sees(values: list[bytes]) -> None:
    seg = fresh()
    for v in values:
        seg.write(v)
    assert seg.read() == (2 * len(values), values[-1])
    out = bytearray(64)
    seq, n = seg.read_into(out)
    assert (seq, bytes(out[:n])) == (2 * len(values), values[-1])


def test_a_value_larger_than_the_capacity_is_refused_and_the_old_value_kept() -> None:
    seg = fresh(8)
    seg.write(b"12345678")
    with pytest.raises(IxmError, match="capacity"):
        seg.write(b"123456789")
    assert seg.read() == (2, b"12345678")


def test_a_writer_that_died_mid_write_is_repaired_by_the_next_writer() -> None:
    seg = fresh()
    seg.write(b"old")
    seq = seg.begin_write()  # and never end_write: the counter stays odd
    seg.target(seq)[:4] = b"torn"
    assert seg.seq & 1
    assert seg.write(b"ok") == 4
    assert seg.seq % 2 == 0
    assert seg.read() == (4, b"ok")


def test_readers_see_the_last_complete_value_with_no_error_after_a_writer_died_mid_copy() -> None:
    seg = fresh()
    seg.write(b"first")
    seg.write(b"second")
    seq = seg.begin_write()
    seg.target(seq)[:5] = b"XXXXX"  # half a new value, then the writer is gone
    assert seg.read() == (4, b"second")
    out = bytearray(64)
    assert seg.read_into(out) == (4, 6)
    assert bytes(out[:6]) == b"second"


def test_a_write_before_the_first_one_completed_reads_as_never_written() -> None:
    seg = fresh()
    seq = seg.begin_write()
    seg.target(seq)[:3] = b"abc"
    assert seg.read() == (0, b"")


def test_the_new_value_goes_to_the_slot_readers_are_not_directed_to() -> None:
    seg = fresh(8)
    seg.write(b"A" * 8)
    active_seq, active = seg.active()
    seq = seg.begin_write()
    assert seg.target(seq) is not active
    seg.target(seq)[:8] = b"B" * 8
    assert (active_seq, bytes(active)) == (2, b"A" * 8)  # untouched while the copy is in progress
    seg.end_write(seq, 8)
    assert seg.active()[0] == 4 and bytes(seg.active()[1]) == b"B" * 8


def test_a_segment_is_the_header_and_two_slots_of_exactly_the_capacity() -> None:
    assert SegmentLayout.segment_size(48) == HEADER_SIZE + 2 * 48
    seg = fresh(48)
    assert [len(s) for s in seg.slots] == [48, 48]


class ScriptedCounter:
    """Stands in for the counter view: the reader sees the values of ``script`` in turn (then the last)."""

    def __init__(self, *script: int) -> None:
        self.script = list(script)

    def __getitem__(self, index: int) -> int:
        return self.script.pop(0) if len(self.script) > 1 else self.script[0]


def test_a_reader_that_raced_one_flip_keeps_its_consistent_copy(monkeypatch: pytest.MonkeyPatch) -> None:
    seg = fresh()
    seg.write(b"one")
    seg.write(b"two")  # counter 4; "one" (counter 2) stays in the other slot until the next write starts
    # the reader saw counter 2 before its copy and 4 after it: one flip, its slot was not touched
    monkeypatch.setattr(seg, "counter", ScriptedCounter(2, 4))
    assert seg.read() == (2, b"one")


def test_a_reader_lapped_by_the_writer_retries_and_gets_the_newer_value(monkeypatch: pytest.MonkeyPatch) -> None:
    seg = fresh()
    seg.write(b"one")
    seg.write(b"two")
    # counter 2 before the copy, 5 after: the write after "two" started in the slot being copied
    monkeypatch.setattr(seg, "counter", ScriptedCounter(2, 5, 4, 4))
    assert seg.read() == (4, b"two")


def test_a_reader_lapped_by_a_live_writer_for_too_long_gives_up_with_a_clear_error(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(layout_mod, "MAX_LAPPED_WAIT", 0.01)
    seg = fresh()
    seg.write(b"a")

    class AlwaysLapped(ScriptedCounter):
        def __init__(self) -> None:
            super().__init__()
            self.calls = 0

        def __getitem__(self, index: int) -> int:
            self.calls += 1
            return 2 if self.calls % 2 else 7

    monkeypatch.setattr(seg, "counter", AlwaysLapped())
    with pytest.raises(IxmError, match="overwrote"):
        seg.read()
    with pytest.raises(IxmError, match="overwrote"):
        seg.read_into(bytearray(8))


def test_a_buffer_that_is_not_an_ixm_segment_is_rejected() -> None:
    with pytest.raises(IxmError, match="not an IXM"):
        SegmentLayout(memoryview(bytearray(HEADER_SIZE + 8)))
    with pytest.raises(IxmError, match="smaller"):
        SegmentLayout(memoryview(bytearray(10)))


def test_a_header_claiming_more_payload_than_the_mapping_is_rejected() -> None:
    buf = bytearray(SegmentLayout.segment_size(64))
    SegmentLayout.initialize(memoryview(buf), 11, 64, 0, "x")
    with pytest.raises(IxmError, match="claims"):
        SegmentLayout(memoryview(buf)[: HEADER_SIZE + 8])
    with pytest.raises(IxmError, match="claims"):  # room for one slot only
        SegmentLayout(memoryview(buf)[: HEADER_SIZE + 64])


def test_reads_are_never_torn_while_another_thread_writes() -> None:
    seg = fresh(4096)
    stop = threading.Event()

    def writer() -> None:
        i = 0
        while not stop.is_set():
            seg.write(bytes([i % 256]) * 4096)
            i += 1

    t = threading.Thread(target=writer)
    t.start()
    try:
        for _ in range(2000):
            _seq, data = seg.read()
            assert data == b"" or data == bytes([data[0]]) * 4096
    finally:
        stop.set()
        t.join(5)


def test_the_header_written_by_the_daemon_is_the_one_initialize_writes() -> None:
    seg = fresh()
    assert bytes(seg.buf[:HEADER_SIZE]) == SegmentLayout.header(seg.type_code, seg.capacity, seg.count, seg.type_name)


@given(st.lists(st.tuples(st.binary(max_size=64), st.booleans()), min_size=1, max_size=30))
def test_after_any_mix_of_complete_and_abandoned_writes_readers_get_the_last_complete_value(
    writes: list[tuple[bytes, bool]],
) -> None:
    seg = fresh()
    last: tuple[int, bytes] = (0, b"")
    for value, completes in writes:
        seq = seg.begin_write()
        seg.target(seq)[: len(value)] = value
        if completes:
            seg.end_write(seq, len(value))
            last = (seq, value)
        # else: the writer died here, mid-copy or just before publishing
        assert seg.read() == last


def test_a_reader_spinning_on_the_counter_of_a_live_writer_in_another_process_never_sees_it_go_back() -> None:
    """Regression: ``struct.pack_into`` zeroes its target before packing, so a reader that polled the counter
    while another process stored it saw 0 (about 1% of reads); values read then came from the wrong slot.
    The counter is now one aligned 8-byte store: it only ever grows, and every value read is whole."""
    import mmap
    import os
    import time

    capacity = 16
    shared = mmap.mmap(-1, SegmentLayout.segment_size(capacity))
    seg = SegmentLayout.initialize(memoryview(shared), type_code=11, capacity=capacity, count=0, type_name="x")
    seg.write((0).to_bytes(16, "little"))
    pid = os.fork()
    if pid == 0:  # the writer: value k is k written twice, so a torn or mixed copy shows
        try:
            k = 0
            end = time.monotonic() + 0.4
            while time.monotonic() < end:
                for _ in range(200):
                    k += 1
                    seg.write(k.to_bytes(8, "little") * 2)
        finally:
            os._exit(0)
    try:
        last = 0
        reads = 0
        deadline = time.monotonic() + 10
        while os.waitpid(pid, os.WNOHANG) == (0, 0):
            assert time.monotonic() < deadline
            counter = seg.seq
            assert counter >= last, f"counter went back from {last} to {counter}"
            last = counter
            seq, data = seg.read()
            assert data[:8] == data[8:], f"mixed value at counter {seq}"
            assert int.from_bytes(data[:8], "little") == seq // 2 - 1
            reads += 1
        assert reads > 100
    finally:
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)
        seg.release()
        shared.close()
