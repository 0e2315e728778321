"""RingLayout and RingCursor: message numbering, drop-oldest, consistency under any interleaving, lying rings."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.msg.runtime import FrameBuffer
from mrosd.shm.ring import HEADER_SIZE, RingCursor, RingLayout, dir_entries, ring_size, slot_stride
from mrosd.wire.framing import LARGE_FRAME
from mrosd.wire.spares import SparePool


def fresh(slots: int = 4, capacity: int = 64, head: int = 0) -> RingLayout:
    return RingLayout.initialize(memoryview(bytearray(ring_size(slots, capacity))), slots, capacity, head)


def content(m: int, length: int) -> bytes:
    """Message m's bytes: every byte differs from the same position of m - slots (a torn copy shows)."""
    return bytes((m * 7 + i) % 251 for i in range(length))


def test_layout_round_trip_and_sizes() -> None:
    ring = fresh(slots=3, capacity=100)
    again = RingLayout(ring.buf)
    assert (again.slots, again.capacity, again.head, again.retired) == (3, 100, 0, False)
    assert slot_stride(100) == 64 + 128
    assert ring_size(3, 100) == HEADER_SIZE + 8 * dir_entries(3) + 3 * 192 and dir_entries(3) == 16


def test_the_writer_chooses_slots_and_readers_follow_the_directory() -> None:
    ring = fresh(slots=3)
    cur = RingCursor(ring, 1)
    ring.write(b"one", slot=2)
    ring.write(b"two", slot=0)
    ring.write(b"three", slot=2)  # message 1's slot reused: it is lost to a reader that did not take it yet
    assert cur.read() == b"two" and cur.dropped == 1 and cur.read() == b"three"
    assert [ring.held(s) for s in range(3)] == [2, 0, 3]
    got = RingCursor(ring, 2).view()
    assert got is not None and bytes(got[1]) == b"two" and ring.slot_of(2) == 0
    got[1].release()


def test_a_directory_naming_a_slot_the_ring_lacks_is_a_protocol_error() -> None:
    ring = fresh(slots=2)
    ring.write(b"x")
    ring._dir[1] = 7
    with pytest.raises(RemoteProtocolError, match="directory"):
        RingCursor(ring, 1).read()


def test_a_directory_pointing_at_an_older_message_is_a_protocol_error() -> None:
    ring = fresh(slots=2)
    ring.write(b"x", slot=0)
    ring.write(b"y", slot=1)
    ring._dir[2] = 0  # message 2 "is" in slot 0, which holds message 1
    with pytest.raises(RemoteProtocolError):
        RingCursor(ring, 2).read()


def test_messages_are_read_in_order_once() -> None:
    ring = fresh()
    cur = RingCursor(ring, 1)
    assert cur.read() is None
    for m in range(1, 4):
        assert ring.write(content(m, m * 5)) == m
    assert [cur.read() for _ in range(4)] == [content(1, 5), content(2, 10), content(3, 15), None]
    assert cur.dropped == 0


def test_copies_into_a_pool_reuse_a_buffer_nothing_holds_and_wait_word_round_trips() -> None:
    big = LARGE_FRAME + 1
    ring = fresh(capacity=big)
    cur = RingCursor(ring, 1)
    pool = SparePool()
    ring.write(content(1, big))
    first = cur.read(pool)
    assert type(first) is FrameBuffer and first == content(1, big)
    first_id = id(first)
    del first
    ring.write(content(2, big))
    again = cur.read(pool)
    assert id(again) == first_id and again == content(2, big)  # refilled in place
    ring.write(content(3, 40))
    assert type(cur.read(pool)) is bytes  # a small message is copied into bytes, as TCPROS frames are
    assert not ring.waiting
    ring.waiting = True
    assert RingLayout(ring.buf).waiting  # a reader's view of the same bytes sees it


def test_a_slow_reader_loses_the_oldest_and_counts_them() -> None:
    ring = fresh(slots=4)
    cur = RingCursor(ring, 1)
    for m in range(1, 11):
        ring.write(content(m, 8))
    got = []
    while (data := cur.read()) is not None:
        got.append(data)
    assert got == [content(m, 8) for m in range(7, 11)]
    assert cur.dropped == 6


def test_a_replacement_ring_continues_the_numbering() -> None:
    ring = fresh(head=41)
    cur = RingCursor(ring, 42)
    assert ring.write(b"x") == 42
    assert cur.read() == b"x"


def test_a_message_larger_than_a_slot_is_refused_and_nothing_is_published() -> None:
    ring = fresh(capacity=8)
    with pytest.raises(LocalProtocolError):
        ring.write(b"123456789")
    assert ring.head == 0


def test_write_parts_equals_the_joined_write() -> None:
    ring = fresh()
    ring.write_parts([b"ab", memoryview(b"cd"), bytearray(b"e")], 5)
    assert RingCursor(ring, 1).read() == b"abcde"


def test_a_zero_copy_view_is_intact_until_its_slot_is_overwritten() -> None:
    ring = fresh(slots=3)
    ring.write(b"first")
    cur = RingCursor(ring, 1)
    got = cur.view()
    assert got is not None
    m, view = got
    assert bytes(view) == b"first" and view.readonly and cur.intact(m)
    ring.write(b"2")
    ring.write(b"3")
    assert cur.intact(m)
    ring.write(b"4")  # slot of message 1 reused
    assert not cur.intact(m)
    view.release()


# a publisher that lies ------------------------------------------------------------------------------------


def test_a_length_beyond_the_slot_is_a_protocol_error_not_an_overread() -> None:
    ring = fresh(capacity=64)
    ring.write(b"ok")
    ring.words[0][1] = 1 << 40
    with pytest.raises(RemoteProtocolError, match="claims"):
        RingCursor(ring, 1).read()


def test_a_head_that_goes_back_is_a_protocol_error() -> None:
    ring = fresh()
    for _ in range(3):
        ring.write(b"x")
    cur = RingCursor(ring, 4)
    ring._head[0] = 1
    with pytest.raises(RemoteProtocolError, match="went back"):
        cur.read()


def test_a_slot_older_than_the_head_says_is_a_protocol_error() -> None:
    ring = fresh()
    ring._head[0] = 2  # head claims two messages, slots hold none
    with pytest.raises(RemoteProtocolError):
        RingCursor(ring, 1).read()


def test_a_huge_head_is_skipped_arithmetically() -> None:
    ring = fresh(slots=2)
    ring._head[0] = 1 << 60
    cur = RingCursor(ring, 1)
    with pytest.raises(RemoteProtocolError):
        cur.read()  # the slots do not hold the messages the head claims
    assert cur.dropped == (1 << 60) - 2


@pytest.mark.parametrize(
    "patch",
    [
        lambda b: b.__setitem__(slice(0, 4), b"XXXX"),
        lambda b: b.__setitem__(slice(8, 12), (0).to_bytes(4, "little")),
        lambda b: b.__setitem__(slice(8, 12), (10**6).to_bytes(4, "little")),
        lambda b: b.__setitem__(slice(16, 24), (1 << 50).to_bytes(8, "little")),
    ],
)
def test_a_bad_header_is_refused(patch) -> None:  # type: ignore[no-untyped-def]
    buf = bytearray(ring_size(2, 64))
    RingLayout.initialize(memoryview(buf), 2, 64).release()
    patch(buf)
    with pytest.raises(RemoteProtocolError):
        RingLayout(memoryview(buf))


@given(st.binary(max_size=HEADER_SIZE + 300))
def test_any_bytes_are_a_ring_or_a_protocol_error(raw: bytes) -> None:
    try:
        ring = RingLayout(memoryview(bytearray(raw)))
    except RemoteProtocolError:
        return
    cur = RingCursor(ring, 1)
    for _ in range(3):
        try:
            data = cur.read()
        except RemoteProtocolError:
            return
        if data is None:
            return
        assert len(data) <= ring.capacity


# any interleaving -----------------------------------------------------------------------------------------


class Writer:
    """A publisher whose copy is split in two halves, so that a reader can run in the middle of it."""

    def __init__(self, ring: RingLayout, lengths: list[int]) -> None:
        self.ring = ring
        self.lengths = lengths
        self.state = 0  # 0 idle, 1 begun, 2 first half copied
        self.m = 0
        self.view: memoryview | None = None

    def step(self) -> None:
        if self.state == 0:
            self.m, self.view = self.ring.begin()
            self.state = 1
        elif self.state == 1:
            assert self.view is not None
            data = content(self.m, self.length)
            self.view[: len(data) // 2] = data[: len(data) // 2]
            self.state = 2
        else:
            assert self.view is not None
            data = content(self.m, self.length)
            self.view[len(data) // 2 : len(data)] = data[len(data) // 2 :]
            self.ring.commit(self.m, len(data))
            self.state = 0

    @property
    def length(self) -> int:
        return self.lengths[self.m % len(self.lengths)]


class Reader:
    """A subscriber whose read is split into begin, copy and finish."""

    def __init__(self, cursor: RingCursor) -> None:
        self.cursor = cursor
        self.state = 0
        self.m = 0
        self.n = 0
        self.data = b""
        self.delivered: list[tuple[int, bytes]] = []

    def step(self) -> None:
        cur = self.cursor
        if self.state == 0:
            got = cur.begin()
            if got is not None:
                self.m, self.n = got
                self.state = 1
        elif self.state == 1:
            self.data = bytes(cur.ring.data[(self.m - 1) % cur.ring.slots][: self.n])
            self.state = 2
        else:
            if cur.finish(self.m):
                self.delivered.append((self.m, self.data))
            self.state = 0


@settings(max_examples=300, deadline=None)
@given(
    slots=st.integers(1, 4),
    lengths=st.lists(st.integers(0, 48), min_size=1, max_size=5),
    schedule=st.lists(st.booleans(), max_size=200),
    latecomer=st.integers(0, 10),
)
def test_no_interleaving_yields_a_torn_or_stale_message(
    slots: int, lengths: list[int], schedule: list[bool], latecomer: int
) -> None:
    ring = fresh(slots=slots, capacity=48)
    writer = Writer(ring, lengths)
    for _ in range(latecomer * 3):
        writer.step()
    start = ring.head + 1
    reader = Reader(RingCursor(ring, start))
    for write in schedule:
        (writer.step if write else reader.step)()
    while writer.state:
        writer.step()
    while reader.state or reader.cursor.available():
        reader.step()
    numbers = [m for m, _ in reader.delivered]
    assert numbers == sorted(set(numbers)), "a message was delivered twice or out of order"
    for m, data in reader.delivered:
        assert data == content(m, writer.lengths[m % len(writer.lengths)]), f"message {m} is torn or stale"
    # every message published after the reader joined was delivered or counted as dropped, exactly once
    assert len(reader.delivered) + reader.cursor.dropped == ring.head - start + 1
