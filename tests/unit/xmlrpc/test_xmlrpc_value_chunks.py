"""A big value encoded once in chunks and spliced into each caller's reply: the stdlib's exact bytes."""

from __future__ import annotations

import datetime
import xmlrpc.client
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.errors import LocalProtocolError
from mrosd.xmlrpc import VALUE_CHUNK, encode_response, encode_value_chunks, reply_parts

text = st.text(st.characters(blacklist_categories=["Cs"], blacklist_characters="\r\x00"), max_size=40)
scalars = st.one_of(
    text,
    st.integers(-(2**31), 2**31 - 1),
    st.booleans(),
    st.floats(allow_nan=False),
    st.none(),
    st.binary(max_size=20).map(xmlrpc.client.Binary),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=5), st.dictionaries(text, inner, max_size=5)),
    max_leaves=30,
)


def stdlib_reply(code: int, status: str, value: Any) -> bytes:
    return xmlrpc.client.dumps(([code, status, value],), methodresponse=True, allow_none=True).encode()


@settings(max_examples=300)
@given(value=values, code=st.sampled_from([1, -1, 0]), status=text)
def test_spliced_reply_is_the_stdlib_reply(value: Any, code: int, status: str) -> None:
    chunks, size = encode_value_chunks(value)
    assert size == sum(map(len, chunks))
    prefix, suffix = reply_parts(code, status)
    spliced = prefix + b"".join(chunks) + suffix
    assert spliced == stdlib_reply(code, status, value)
    assert spliced == encode_response([code, status, value])


def test_long_strings_are_cut_into_chunks_and_escaped_alike() -> None:
    value = {"a": "<&>" * 1_000_000, "b": ["x" * (3 * VALUE_CHUNK), 1.5, None, datetime.datetime(2020, 1, 2)]}
    chunks, _ = encode_value_chunks(value)
    assert len(chunks) > 10 and max(map(len, chunks)) <= 6 * VALUE_CHUNK  # an escaped slice grows 5x at most
    prefix, suffix = reply_parts(1, "ok")
    assert prefix + b"".join(chunks) + suffix == stdlib_reply(1, "ok", value)


def test_encoding_stops_past_the_limit() -> None:
    chunks, size = encode_value_chunks(["y" * VALUE_CHUNK] * 20, limit=4 * VALUE_CHUNK)
    assert chunks == [] and 4 * VALUE_CHUNK < size < 6 * VALUE_CHUNK


@pytest.mark.parametrize("bad", [2**40, {1: "x"}, object()])
def test_unencodable_values_are_local_protocol_errors(bad: Any) -> None:
    with pytest.raises(LocalProtocolError):
        encode_value_chunks([bad])
