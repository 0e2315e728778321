"""The master's HTTP header parser and reply cache, sans IO: untrusted header bytes, cache bounds."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import HttpRefused
from mrosd.master import dispatch
from mrosd.master.dispatch import XmlRpcHttpHandler
from mrosd.master.httpframing import parse_head
from mrosd.xmlrpc import MAX_BODY_SIZE, XmlRpcServer, decode_response, encode_call

header_lines = st.lists(
    st.one_of(
        st.sampled_from([b"Content-Length: 12", b"content-length:7 ", b"Connection: close", b"Expect: 100-continue"]),
        st.binary(max_size=40),
    ),
    max_size=6,
)


@given(st.sampled_from([b"POST / HTTP/1.1", b"POST / HTTP/1.0", b"GET / HTTP/1.1", b"POST /"]), header_lines)
def test_any_header_block_is_either_parsed_within_limits_or_refused_with_a_status(
    line: bytes, fields: list[bytes]
) -> None:
    head = b"\r\n".join([line, *fields])
    try:
        length, keep_alive, expect = parse_head(head)
    except HttpRefused as exc:
        assert exc.status in (400, 405, 411, 413)
        return
    assert 0 <= length <= MAX_BODY_SIZE
    assert isinstance(keep_alive, bool) and isinstance(expect, bool)


def test_a_typical_header_block_gives_length_keep_alive_and_expect() -> None:
    assert parse_head(b"POST /RPC2 HTTP/1.1\r\nHost: x\r\nContent-Length: 42") == (42, True, False)
    assert parse_head(b"POST / HTTP/1.0\r\nContent-Length: 1\r\nConnection: keep-alive") == (1, True, False)
    assert parse_head(b"POST / HTTP/1.1\r\nContent-length: 1\r\nExpect: 100-continue") == (1, True, True)
    with pytest.raises(HttpRefused):
        parse_head(b"POST / HTTP/1.1\r\nContent-Length: %d" % (MAX_BODY_SIZE + 1))


def _handler(state: list[int], reply: Any) -> XmlRpcHttpHandler:
    calls = {"getThing": lambda caller: (1, "", reply), "setThing": lambda caller: state.append(1) or (1, "", 0)}
    return XmlRpcHttpHandler(
        calls, XmlRpcServer({}), cacheable=frozenset({"getThing"}), state_version=lambda: len(state)
    )


def test_cached_replies_are_dropped_when_the_state_changes() -> None:
    state: list[int] = []
    value = ["a"]
    handler = _handler(state, value)
    get = encode_call("getThing", ("/c",))
    first = handler.handle(get)
    value.append("b")  # changed behind the handler's back: still the cached reply
    assert handler.handle(get) is first
    assert isinstance(handler.handle(encode_call("setThing", ("/c",))), bytes)
    again = handler.handle(get)
    assert isinstance(again, bytes) and decode_response(again)[2] == ["a", "b"]


def test_the_reply_cache_keeps_no_more_than_its_byte_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dispatch, "REPLY_CACHE_BYTES", 1000)
    handler = _handler([], "x" * 600)
    get = encode_call("getThing", ("/c",))
    other = encode_call("getThing", ("/d",))
    assert handler.handle(get) is handler.handle(get)  # first reply fits and is kept
    assert handler.handle(other) is not handler.handle(other)  # a second one would exceed the budget


@pytest.mark.parametrize(
    "fields",
    [
        b"Content-Length: 5\r\nContent-Length: 6",
        b"Content-Length: 5\r\ncontent-length: 5",
        b"Content-Length: 5\r\nContent-Length : 60",
        b"Content-Length: 5\r\nTransfer-Encoding: chunked",
        b"Transfer-Encoding: chunked\r\nContent-Length: 5",
        b"Content-Length: 5, 6",
    ],
)
def test_ambiguous_body_framing_is_refused_with_400(fields: bytes) -> None:
    with pytest.raises(HttpRefused) as info:
        parse_head(b"POST / HTTP/1.1\r\nHost: x\r\n" + fields)
    assert info.value.status == 400


@pytest.mark.parametrize(
    "field",
    [
        b"Origin: http://attacker.test:8000",
        b"origin: null",
        b"ORIGIN: http://127.0.0.1:11311",
        b"Sec-Fetch-Mode: no-cors",
        b"Sec-Fetch-Site: cross-site",
    ],
)
def test_a_request_from_a_web_page_is_refused_with_403(field: bytes) -> None:
    """A browser sends Origin with every POST; ROS clients never do (tests/web/test_web_origin_browser.py)."""
    with pytest.raises(HttpRefused) as info:
        parse_head(b"POST / HTTP/1.1\r\nHost: 127.0.0.1:11311\r\n" + field + b"\r\nContent-Length: 5")
    assert info.value.status == 403 and b"web page" in info.value.text


def test_what_ros_clients_send_is_accepted() -> None:
    """rospy's xmlrpc.client, roscpp's XmlRpc++ and mrosd's client; an Origin inside a value is no field."""
    for head in (
        b"POST /RPC2 HTTP/1.1\r\nHost: localhost:11311\r\nAccept-Encoding: gzip\r\nContent-Type: text/xml\r\n"
        b"User-Agent: Python-xmlrpc/3.11\r\nContent-Length: 100",
        b"POST / HTTP/1.1\r\nUser-Agent: XMLRPC++ 0.7\r\nHost: robot:11311\r\nContent-Type: text/xml\r\n"
        b"Content-length: 100",
        b"POST / HTTP/1.1\r\nHost: x\r\nUser-Agent: mrosd\r\nX-Note: origin: none\r\nContent-Length: 100",
    ):
        assert parse_head(head)[0] == 100
