"""Control protocol: exact frames, incremental decoding (the shared TCPROS decoder), limits, malformed input."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import RemoteProtocolError
from mrosd.ixm.protocol import (
    MAX_REQUEST_SIZE,
    Close,
    Open,
    Opened,
    WakeList,
    decode_reply,
    decode_request,
    encode,
)
from mrosd.wire.framing import FrameDecoder


def test_a_close_request_has_these_exact_bytes() -> None:
    assert encode(Close("/k")) == b"\x11\x00\x00\x00\x82\xa2op\xa5close\xa3key\xa2/k"


def test_requests_and_replies_round_trip_through_the_decoder_in_pieces() -> None:
    frames = encode(Open(key="/a", type="float64", mode="w")) + encode(Close("/a"))
    dec = FrameDecoder(MAX_REQUEST_SIZE)
    got = []
    for i in range(len(frames)):
        dec.feed(frames[i : i + 1])
        body = dec.maybe_next_frame()
        if body is not None:
            got.append(decode_request(body))
    assert got == [Open(key="/a", type="float64", mode="w"), Close("/a")]
    opened = Opened(key="/a", type="float64", count=0, max_size=0, capacity=8, mode="w", shm_name="/x")
    assert decode_reply(encode(opened)[4:]) == opened
    assert decode_reply(encode(WakeList(key="/a", generation=2, count=1))[4:]).count == 1


def test_a_frame_over_the_limit_is_refused_before_it_is_buffered() -> None:
    dec = FrameDecoder(MAX_REQUEST_SIZE)
    dec.feed((MAX_REQUEST_SIZE + 1).to_bytes(4, "little"))
    with pytest.raises(RemoteProtocolError, match="frame of 4097 bytes announced, the limit is 4096"):
        dec.maybe_next_frame()


@pytest.mark.parametrize(
    "body", [b"", b"\xc1", b"\x81\xa2op\xa4nope", b"\x81\xa2op\xa4open", b"\x82\xa2op\xa5close\xa3key\x01"]
)
def test_malformed_bodies_are_remote_protocol_errors(body: bytes) -> None:
    with pytest.raises(RemoteProtocolError, match="malformed"):
        decode_request(body)


@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_raise_anything_but_protocol_errors(data: bytes) -> None:
    dec = FrameDecoder(64)
    dec.feed(data)
    try:
        while (body := dec.maybe_next_frame()) is not None:
            decode_request(body)
    except RemoteProtocolError:
        pass


def test_the_daemon_and_the_client_cut_frames_with_the_one_tcpros_decoder() -> None:
    import socket

    from mrosd.ixm.channel import FdReader
    from mrosd.ixm.connection import ClientConnection

    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    with a, b:
        reader = FdReader(a, MAX_REQUEST_SIZE)
        assert type(reader.decoder) is FrameDecoder and reader.decoder.max_size == MAX_REQUEST_SIZE
        b.sendall(encode(Close("/k")) + encode(Close("/j"))[:3])
        assert reader.recv()
        assert reader.next_frame() == encode(Close("/k"))[4:]
        assert reader.next_frame() is None
        reader.close()
    assert type(ClientConnection()._decoder) is FrameDecoder
