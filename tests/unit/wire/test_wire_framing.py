"""Frame decoder: incremental feeding, limits checked before buffering, property round-trips."""

from __future__ import annotations

import itertools
import struct
import tracemalloc
from collections.abc import Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.errors import RemoteProtocolError
from mrosd.wire.framing import (
    GROWTH,
    LARGE_FRAME,
    MAX_FRAME_SIZE,
    FrameBuffer,
    FrameDecoder,
    Response,
    encode_frame,
    frame_prefix,
)
from mrosd.wire.spares import SPARES, SparePool


def pieces(stream: bytes, cuts: list[int]) -> Iterator[bytes]:
    """``stream`` in consecutive pieces of the sizes in ``cuts`` (repeated as needed)."""
    pos = 0
    for step in itertools.cycle(cuts):
        if pos >= len(stream):
            return
        yield stream[pos : pos + step]
        pos += step


def test_a_frame_is_its_length_then_its_body() -> None:
    assert encode_frame(b"\x02\x00\x00\x00hi") == b"\x06\x00\x00\x00\x02\x00\x00\x00hi"


def test_incomplete_input_yields_none_until_the_frame_is_whole() -> None:
    dec = FrameDecoder()
    data = encode_frame(b"hello")
    for i in range(len(data) - 1):
        dec.feed(data[i : i + 1])
        assert dec.maybe_next_frame() is None
    dec.feed(data[-1:])
    assert dec.maybe_next_frame() == b"hello"
    assert dec.maybe_next_frame() is None
    assert dec.buffered == 0


def test_an_empty_frame_is_a_frame() -> None:
    dec = FrameDecoder()
    dec.feed(encode_frame(b""))
    assert dec.maybe_next_frame() == b""


def test_a_four_gigabyte_length_is_refused_before_any_body_arrives() -> None:
    dec = FrameDecoder()
    dec.feed(b"\xff\xff\xff\xff")
    with pytest.raises(RemoteProtocolError, match="limit"):
        dec.maybe_next_frame()
    assert dec.buffered == 4


def test_the_limit_is_per_decoder() -> None:
    dec = FrameDecoder(max_size=10)
    dec.feed(encode_frame(b"x" * 10))
    assert dec.maybe_next_frame() == b"x" * 10
    dec.feed(encode_frame(b"x" * 11))
    with pytest.raises(RemoteProtocolError):
        dec.maybe_next_frame()
    assert MAX_FRAME_SIZE == 1 << 30


def test_many_frames_survive_buffer_compaction() -> None:
    dec = FrameDecoder()
    bodies = [bytes([i % 256]) * 1000 for i in range(300)]
    dec.feed(b"".join(encode_frame(b) for b in bodies))
    out = []
    while (frame := dec.maybe_next_frame()) is not None:
        out.append(frame)
    assert out == bodies


@given(st.lists(st.binary(max_size=200), max_size=20), st.lists(st.integers(1, 50), min_size=1, max_size=30))
def test_frames_split_anywhere_come_out_whole_and_in_order(bodies: list[bytes], cuts: list[int]) -> None:
    stream = b"".join(encode_frame(b) for b in bodies)
    dec = FrameDecoder()
    out: list[bytes] = []
    for piece in pieces(stream, cuts):
        dec.feed(piece)
        while (frame := dec.maybe_next_frame()) is not None:
            out.append(frame)
    assert out == bodies


@given(st.binary(max_size=400))
def test_arbitrary_bytes_never_break_the_decoder(data: bytes) -> None:
    dec = FrameDecoder(max_size=100)
    dec.feed(data)
    try:
        while dec.maybe_next_frame() is not None:
            pass
    except RemoteProtocolError:
        pass


@given(st.lists(st.binary(max_size=200), max_size=20), st.lists(st.integers(1, 50), min_size=1, max_size=30))
def test_feed_frames_agrees_with_maybe_next_frame_however_the_stream_is_cut(
    bodies: list[bytes], cuts: list[int]
) -> None:
    stream = b"".join(encode_frame(b) for b in bodies)
    dec = FrameDecoder()
    out: list[bytes] = []
    for piece in pieces(stream, cuts):
        out.extend(dec.feed_frames(piece))
    assert out == bodies
    assert dec.buffered == 0


def test_feed_frames_refuses_an_oversized_length_without_buffering_the_body() -> None:
    dec = FrameDecoder(max_size=10)
    assert dec.feed_frames(encode_frame(b"ok")) == [b"ok"]
    with pytest.raises(RemoteProtocolError):
        dec.feed_frames(b"\xff\xff\xff\x7f" + b"x" * 10)


@settings(deadline=None, max_examples=50)
@given(
    st.lists(st.sampled_from([0, 3, 100, 70_000, 200_000]), max_size=6),
    st.lists(st.integers(1, 150_000) | st.integers(1, 8), min_size=1, max_size=10).filter(lambda c: max(c) > 1000),
)
def test_large_frames_spanning_reads_come_out_whole(sizes: list[int], cuts: list[int]) -> None:
    bodies = [bytes([i % 251]) * n for i, n in enumerate(sizes)]
    stream = b"".join(encode_frame(b) for b in bodies)
    dec = FrameDecoder()
    out: list[bytes] = []
    for piece in pieces(stream, cuts):
        out.extend(bytes(f) for f in dec.feed_frames(piece))
    assert out == bodies
    assert dec.buffered == 0


def _receive_in_place(dec: FrameDecoder, stream: bytes, cuts: list[int]) -> list[bytes | bytearray]:
    """Play ``stream`` through get_buffer()/buffer_updated() as a socket would, reads capped by ``cuts``."""
    out: list[bytes | bytearray] = []
    pos = 0
    i = 0
    while pos < len(stream):
        buf = dec.get_buffer()
        assert len(buf) > 0
        n = min(cuts[i % len(cuts)], len(buf), len(stream) - pos)
        buf[:n] = stream[pos : pos + n]
        del buf
        out.extend(dec.buffer_updated(n))
        pos += n
        i += 1
    return out


@settings(deadline=None, max_examples=50)
@given(
    st.lists(st.sampled_from([0, 3, 100, 70_000, 200_000]), max_size=6),
    st.lists(st.integers(1, 150_000) | st.integers(1, 8), min_size=1, max_size=10),
)
def test_receiving_into_the_lent_buffer_yields_the_same_frames_however_reads_are_cut(
    sizes: list[int], cuts: list[int]
) -> None:
    bodies = [bytes([i % 251]) * n for i, n in enumerate(sizes)]
    dec = FrameDecoder()
    out = _receive_in_place(dec, b"".join(encode_frame(b) for b in bodies), cuts)
    assert out == bodies
    assert dec.buffered == 0


def test_a_large_frame_is_received_into_its_own_buffer_which_ends_at_the_frame() -> None:
    body = bytes(range(256)) * 1024  # 256 KiB
    stream = encode_frame(body) + encode_frame(b"next")
    dec = FrameDecoder()
    first = dec.get_buffer()
    first[:1000] = stream[:1000]
    del first
    assert dec.buffer_updated(1000) == []
    pos = 1000
    frames: list[bytes | bytearray] = []
    while not frames:
        rest = dec.get_buffer()
        assert 0 < len(rest) <= 4 + len(body) - pos  # never past the frame: the next frame never lands in it
        n = len(rest)
        rest[:] = stream[pos : pos + n]
        del rest
        frames = dec.buffer_updated(n)
        pos += n
    assert pos == 4 + len(body)
    (frame,) = frames
    assert isinstance(frame, FrameBuffer) and frame == body
    assert _receive_in_place(dec, stream[4 + len(body) :], [100]) == [b"next"]


@pytest.mark.parametrize("path", ["lent", "fed"])
def test_a_claimed_gigabyte_costs_what_arrived_not_what_was_claimed(path: str) -> None:
    dec = FrameDecoder()
    claim = struct.pack("<I", MAX_FRAME_SIZE) + b"12345"
    chunk = b"x" * (1024 * 1024)
    tracemalloc.start()
    try:
        if path == "lent":
            for data in (claim, chunk):
                got = 0
                while got < len(data):
                    buf = dec.get_buffer()
                    n = min(len(buf), len(data) - got)
                    buf[:n] = data[got : got + n]
                    del buf
                    assert dec.buffer_updated(n) == []
                    got += n
                if data is claim:
                    assert tracemalloc.get_traced_memory()[1] < 4 * LARGE_FRAME
            dec.get_buffer()
        else:
            assert dec.feed_frames(claim) == []
            assert tracemalloc.get_traced_memory()[1] < 4 * LARGE_FRAME
            assert dec.feed_frames(chunk) == []
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert dec.buffered == 5 + len(chunk)
    assert peak < 2 * GROWTH * len(chunk)  # follows the megabyte that arrived, not the gigabyte announced


@settings(deadline=None, max_examples=30)
@given(
    st.integers(LARGE_FRAME + 1, 2 * 1024 * 1024),
    st.lists(st.integers(1, 8) | st.integers(4096, 300_000), min_size=1, max_size=8).filter(lambda c: max(c) > 8),
)
def test_lent_buffers_grow_with_the_data_and_stay_bounded_by_it(size: int, cuts: list[int]) -> None:
    body = bytes([size % 251]) * size
    stream = encode_frame(body)
    dec = FrameDecoder(spares=SparePool())  # no spare of the process's pool (that memory is already there)
    pos = 0
    i = 0
    out: list[bytes | bytearray] = []
    while pos < len(stream):
        buf = dec.get_buffer()
        assert len(buf) + dec.buffered <= max(LARGE_FRAME + 4, GROWTH * dec.buffered)
        n = min(cuts[i % len(cuts)], len(buf), len(stream) - pos)
        buf[:n] = stream[pos : pos + n]
        del buf
        out.extend(dec.buffer_updated(n))
        pos += n
        i += 1
    assert out == [body]


def test_the_lent_buffer_path_refuses_an_oversized_length_before_allocating() -> None:
    dec = FrameDecoder(max_size=10)
    buf = dec.get_buffer()
    buf[:14] = b"\xff\xff\xff\x7f" + b"x" * 10
    del buf
    with pytest.raises(RemoteProtocolError):
        dec.buffer_updated(14)


def test_received_hands_back_the_bytes_written_into_the_lent_buffer() -> None:
    dec = FrameDecoder()
    buf = dec.get_buffer()
    buf[:3] = b"abc"
    del buf
    assert bytes(dec.received(3)) == b"abc"


def test_a_delivered_large_frame_never_changes_and_is_reused_only_once_released() -> None:
    first, second, third = (bytes([i]) * (3 * LARGE_FRAME) for i in (1, 2, 3))
    dec = FrameDecoder(spares=SparePool())
    (held,) = _receive_in_place(dec, encode_frame(first), [LARGE_FRAME])
    view = memoryview(held)[10:20]  # as a decoded message's payload view would
    del held
    (other,) = _receive_in_place(dec, encode_frame(second), [LARGE_FRAME])
    assert view.obj is not other and bytes(view) == first[10:20]  # still referenced: never overwritten
    other_id = id(other)
    del view, other
    (again,) = _receive_in_place(dec, encode_frame(third), [LARGE_FRAME])
    assert id(again) == other_id and again == third  # nobody held it: received into it again, no allocation


def test_frames_held_a_few_at_a_time_are_received_into_the_same_buffers_again() -> None:
    """A bridge holds a few frames while its clients read them: the pool keeps that many to reuse."""
    dec = FrameDecoder(spares=SparePool())
    size = 3 * LARGE_FRAME
    held = [_receive_in_place(dec, encode_frame(bytes([i]) * size), [LARGE_FRAME])[0] for i in range(4)]
    ids = {id(b) for b in held}
    for step in range(3 * 4):
        oldest = held.pop(0)  # released: one of the spares is free again
        del oldest
        body = bytes([100 + step]) * size
        (frame,) = _receive_in_place(dec, encode_frame(body), [LARGE_FRAME])
        assert id(frame) in ids and frame == body
        held.append(frame)
        assert all(b[0] == b[-1] for b in held)  # a frame still held was never written into


def test_the_connections_of_a_process_share_one_bounded_pool_of_spares() -> None:
    """Each link used to keep its newest large buffer however many links there were (six publishers latching
    40 MiB: 240 MiB kept in a bridge after every message was sent and dropped); the pool is one per process."""
    pool = SparePool(max_bytes=4 * LARGE_FRAME)
    links = [FrameDecoder(spares=pool) for _ in range(SPARES)]
    size = 2 * LARGE_FRAME
    held = [_receive_in_place(dec, encode_frame(bytes([i]) * size), [LARGE_FRAME])[0] for i, dec in enumerate(links)]
    assert len(pool) == 2 and pool.size == 2 * size  # the newest two: the rest are the receivers' alone
    kept = {id(held[-1]), id(held[-2])}
    del held
    (frame,) = _receive_in_place(links[0], encode_frame(b"z" * size), [LARGE_FRAME])
    assert frame == b"z" * size and id(frame) in kept  # a buffer another link delivered, received into again


@settings(deadline=None, max_examples=50)
@given(st.lists(st.integers(1, 200), min_size=1, max_size=6), st.booleans())
def test_the_first_frame_has_the_header_limit_and_later_ones_the_message_limit(cuts: list[int], lent: bool) -> None:
    header, small, big = b"h" * 300, b"m" * 5, b"x" * 50
    stream = encode_frame(header) + encode_frame(small) + encode_frame(big)
    out: list[bytes | bytearray] = []
    dec = FrameDecoder(max_size=10, header_max_size=1000)
    # the 300-byte header passes its limit and the 5-byte message its own: only the 50-byte one is refused
    with pytest.raises(RemoteProtocolError, match="50 bytes announced, the limit is 10"):
        if lent:
            _receive_in_place(dec, stream, cuts)
        else:
            for piece in pieces(stream, cuts):
                out.extend(dec.feed_frames(piece))
    assert out == [header, small][: len(out)]
    strict = FrameDecoder(max_size=1000, header_max_size=10)
    with pytest.raises(RemoteProtocolError, match="300 bytes announced, the limit is 10"):
        strict.feed_frames(stream)


# --- service responses: an ok byte before each frame after the header -----------------------------------


def test_a_service_response_is_an_ok_byte_then_a_frame() -> None:
    assert encode_frame(b"hi", ok=True) == b"\x01\x02\x00\x00\x00hi"
    assert encode_frame(b"no", ok=False) == b"\x00\x02\x00\x00\x00no"
    assert frame_prefix(7) == struct.pack("<I", 7) and frame_prefix(7, ok=True) == b"\x01" + struct.pack("<I", 7)


def _response_stream(header: bytes, answers: list[tuple[int, bytes]]) -> bytes:
    return encode_frame(header) + b"".join(bytes([flag]) + encode_frame(body) for flag, body in answers)


def _feed_responses(dec: FrameDecoder, stream: bytes, cuts: list[int]) -> list[Response]:
    out: list[Response] = []
    for piece in pieces(stream, cuts):
        out.extend(dec.feed_responses(piece))
    return out


_answers = st.lists(
    st.tuples(
        st.integers(0, 255),
        st.one_of(st.binary(max_size=40), st.integers(LARGE_FRAME + 1, LARGE_FRAME + 3000).map(lambda n: b"L" * n)),
    ),
    max_size=5,
)


@settings(deadline=None, max_examples=80)
@given(st.binary(max_size=60), _answers, st.lists(st.integers(1, 70_000), min_size=1, max_size=6))
def test_any_cut_of_a_service_stream_yields_the_same_header_responses_and_ok_flags(
    header: bytes, answers: list[tuple[int, bytes]], cuts: list[int]
) -> None:
    dec = FrameDecoder(header_max_size=100, ok_byte=True)
    got = _feed_responses(dec, _response_stream(header, answers), cuts)
    # the header has no ok byte and comes out as ok; a response is ok exactly when its byte is 1
    assert got == [(True, header)] + [(flag == 1, body) for flag, body in answers]
    assert dec.buffered == 0


@settings(deadline=None, max_examples=50)
@given(st.lists(st.tuples(st.booleans(), st.binary(max_size=30)), max_size=6), st.lists(st.integers(1, 9), min_size=1))
def test_without_a_header_limit_every_frame_has_an_ok_byte(answers: list[tuple[bool, bytes]], cuts: list[int]) -> None:
    stream = b"".join(encode_frame(body, ok=ok) for ok, body in answers)
    assert _feed_responses(FrameDecoder(ok_byte=True), stream, cuts) == answers


@settings(deadline=None, max_examples=50)
@given(st.integers(11, 2**32 - 1), st.integers(0, 255), st.lists(st.integers(1, 6), min_size=1))
def test_a_lying_response_length_is_refused_before_its_body_is_kept(claim: int, flag: int, cuts: list[int]) -> None:
    dec = FrameDecoder(max_size=10, header_max_size=100, ok_byte=True)
    stream = encode_frame(b"h" * 50) + bytes([flag]) + struct.pack("<I", claim)
    got: list[Response] = []
    with pytest.raises(RemoteProtocolError, match=f"{claim} bytes announced, the limit is 10"):
        for piece in pieces(stream, cuts):
            got.extend(dec.feed_responses(piece))
    assert got == [(True, b"h" * 50)][: len(got)]
    assert dec.buffered <= 4  # at most the length prefix's first bytes: nothing of the frame was kept


def test_a_response_claiming_a_gigabyte_costs_what_arrived() -> None:
    dec = FrameDecoder(ok_byte=True)
    claim = b"\x01" + struct.pack("<I", MAX_FRAME_SIZE) + b"12345"
    chunk = b"x" * (1024 * 1024)
    tracemalloc.start()
    try:
        assert dec.feed_responses(claim) == []
        assert tracemalloc.get_traced_memory()[1] < 4 * LARGE_FRAME
        assert dec.feed_responses(chunk) == []
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert dec.buffered == 5 + 1024 * 1024
    assert peak < 2 * GROWTH * 1024 * 1024


def test_a_large_response_keeps_its_ok_flag_and_arrives_as_one_buffer() -> None:
    body = bytes(range(256)) * 1000
    dec = FrameDecoder(ok_byte=True)
    stream = encode_frame(body, ok=False) + encode_frame(b"after", ok=True)
    got = _feed_responses(dec, stream, [1000])
    assert got == [(False, body), (True, b"after")]
    assert isinstance(got[0][1], FrameBuffer)


def test_the_ok_byte_mode_and_the_frame_methods_are_not_mixed() -> None:
    with pytest.raises(RuntimeError, match="ok_byte=True"):
        FrameDecoder().feed_responses(encode_frame(b"x", ok=True))
    dec = FrameDecoder(ok_byte=True)
    dec.feed(encode_frame(b"x", ok=True))
    with pytest.raises(RuntimeError, match="feed_responses"):
        dec.maybe_next_frame()


# --- the connection header phase (header_max_size): memory follows what the peer sent --------------------


def test_a_claimed_header_costs_only_what_arrived() -> None:
    """A 4 MiB header claim and one byte of it: a small fixed receive buffer and the 5 bytes, nothing more."""
    from mrosd.wire.framing import HEADER_RECV_SIZE

    dec = FrameDecoder(MAX_FRAME_SIZE, header_max_size=4 * 1024 * 1024)
    buf = dec.get_buffer()
    assert len(buf) == HEADER_RECV_SIZE
    stream = struct.pack("<I", 4 * 1024 * 1024) + b"x"
    buf[: len(stream)] = stream
    del buf
    assert dec.buffer_updated(len(stream)) == []
    assert dec.buffered == len(stream)
    assert len(dec.get_buffer()) == HEADER_RECV_SIZE  # no buffer sized by the claim


def test_the_header_claim_is_judged_before_anything_is_kept() -> None:
    dec = FrameDecoder(MAX_FRAME_SIZE, header_max_size=1000)
    buf = dec.get_buffer()
    buf[:5] = struct.pack("<I", 1001) + b"x"
    del buf
    with pytest.raises(RemoteProtocolError):
        dec.buffer_updated(5)


@settings(deadline=None, max_examples=50)
@given(
    st.integers(0, 20_000),
    st.lists(st.sampled_from([0, 5, 70_000]), max_size=3),
    st.lists(st.integers(1, 9000), min_size=1, max_size=6),
)
def test_a_header_in_any_pieces_then_frames_decode_as_sent(header_size: int, sizes: list[int], cuts: list[int]) -> None:
    header = bytes(range(256)) * (header_size // 256) + b"h" * (header_size % 256)
    bodies = [bytes([i % 251]) * size for i, size in enumerate(sizes)]
    stream = encode_frame(header) + b"".join(encode_frame(b) for b in bodies)
    dec = FrameDecoder(MAX_FRAME_SIZE, header_max_size=64 * 1024)
    got = _receive_in_place(dec, stream, cuts)
    assert [bytes(f) for f in got] == [header, *bodies]
    assert dec.max_size == MAX_FRAME_SIZE
