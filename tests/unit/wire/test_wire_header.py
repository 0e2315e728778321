"""Connection header codec: exact bytes both ways, limits, malformed input, property round-trips."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.wire.header import (
    MAX_HEADER_SIZE,
    ConnectionHeader,
    decode_connection_header,
    decode_header,
    encode_header,
)

# The example from the ROS wiki (TCPROS page): a subscriber header for /chatter.
WIKI = (
    b"\xb0\x00\x00\x00"
    b"\x20\x00\x00\x00message_definition=string data\n\n"
    b"\x25\x00\x00\x00callerid=/rostopic_4767_1316912741557"
    b"\x0a\x00\x00\x00latching=1"
    b"\x27\x00\x00\x00md5sum=992ce8a1687cec8c8bd883ec73ca41d1"
    b"\x0e\x00\x00\x00topic=/chatter"
    b"\x14\x00\x00\x00type=std_msgs/String"
)


def test_the_wiki_example_decodes_to_its_fields() -> None:
    fields = decode_header(WIKI[4:])
    assert fields == {
        "message_definition": "string data\n\n",
        "callerid": "/rostopic_4767_1316912741557",
        "latching": "1",
        "md5sum": "992ce8a1687cec8c8bd883ec73ca41d1",
        "topic": "/chatter",
        "type": "std_msgs/String",
    }
    assert struct.unpack("<I", WIKI[:4])[0] == len(WIKI) - 4


def test_encoding_the_wiki_fields_in_the_same_order_gives_the_same_bytes() -> None:
    assert encode_header(decode_header(WIKI[4:])) == WIKI


def test_values_may_contain_equals_signs_and_newlines() -> None:
    data = encode_header({"error": "a=b\nc"})
    assert decode_header(data[4:]) == {"error": "a=b\nc"}


def test_unknown_keys_are_kept_in_extra_and_sent_back() -> None:
    hdr = decode_connection_header(encode_header({"topic": "/a", "x_custom": "1"})[4:])
    assert hdr.topic == "/a"
    assert hdr.extra == {"x_custom": "1"}
    assert decode_header(encode_header(hdr)[4:]) == {"topic": "/a", "x_custom": "1"}


def test_flags_accept_one_and_true() -> None:
    assert ConnectionHeader(latching="1").flag("latching")
    assert ConnectionHeader(tcp_nodelay="true").flag("tcp_nodelay")
    assert not ConnectionHeader(latching="0").flag("latching")
    assert not ConnectionHeader().flag("probe")


@pytest.mark.parametrize(
    ("body", "reason"),
    [
        (b"\x05\x00\x00\x00ab", "claims 5 bytes"),
        (b"\x03\x00\x00\x00abc", "not key=value"),
        (b"\x04\x00\x00\x00=abc", "not key=value"),
        (b"\x03\x00", "truncated"),
        (b"\x05\x00\x00\x00a=\xff\xfe\xfd"[:9], "not UTF-8"),
    ],
)
def test_malformed_headers_are_refused_with_a_reason(body: bytes, reason: str) -> None:
    with pytest.raises(RemoteProtocolError, match=reason):
        decode_header(body)


def test_an_oversized_header_is_refused_both_ways() -> None:
    with pytest.raises(RemoteProtocolError, match="MAX_HEADER_SIZE"):
        decode_header(bytes(MAX_HEADER_SIZE + 1))
    with pytest.raises(LocalProtocolError, match="MAX_HEADER_SIZE"):
        encode_header({"message_definition": "x" * MAX_HEADER_SIZE})


def test_keys_with_equals_signs_cannot_be_encoded() -> None:
    with pytest.raises(LocalProtocolError):
        encode_header({"a=b": "c"})


keys = st.text(st.characters(exclude_characters="=", codec="utf-8"), min_size=1, max_size=20)
values = st.text(st.characters(codec="utf-8"), max_size=50)


@given(st.dictionaries(keys, values, max_size=10))
def test_any_header_round_trips(fields: dict[str, str]) -> None:
    data = encode_header(fields)
    assert decode_header(data[4:]) == fields


@given(st.binary(max_size=300))
def test_arbitrary_bytes_either_decode_or_raise_remote_protocol_error(data: bytes) -> None:
    try:
        fields = decode_header(data)
    except RemoteProtocolError:
        return
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in fields.items())
