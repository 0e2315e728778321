"""SegmentLayout: header round trip, seqlock semantics, torn-read detection, size limits."""

from __future__ import annotations

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
    seg.begin_write()  # and never end_write: the counter stays odd
    assert seg.seq & 1
    seg.write(b"ok")
    assert seg.seq % 2 == 0
    assert seg.read()[1] == b"ok"


def test_a_reader_gives_up_with_a_clear_error_when_the_counter_stays_odd(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(layout_mod, "MAX_TORN_WAIT", 0.01)
    seg = fresh()
    seg.begin_write()
    with pytest.raises(IxmError, match="died"):
        seg.read()


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


def test_the_generation_is_published_in_the_header() -> None:
    seg = fresh()
    assert seg.generation == 0
    assert seg.bump_generation() == 1
    assert SegmentLayout(seg.buf).generation == 1
