"""The XML-RPC codec: the fast path accepts exactly what the full decoder accepts, DTDs and entities are refused.

Property: for any input (generated calls, mutated ones, tag swaps, random bytes) the fast path either defers
(None) or returns what the full decoder returns; wherever the full decoder refuses, so does the fast path.
"""

from __future__ import annotations

import xmlrpc.client
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.errors import RemoteProtocolError
from mrosd.xmlrpc import (
    INCREMENTAL_DECODE_SIZE,
    Fault,
    decode_call,
    decode_call_async,
    decode_response,
    encode_call,
    encode_response,
    fast_decode_call,
    fast_encode_response,
)

scalars = st.one_of(
    st.text(alphabet=st.characters(min_codepoint=0, max_codepoint=0x7F), max_size=12),
    st.text(max_size=6),
    st.integers(-(2**31), 2**31 - 1),
    st.booleans(),
    st.floats(allow_nan=False),
)


def stdlib(body: bytes) -> tuple[str, tuple[Any, ...]] | None:
    try:
        params, method = xmlrpc.client.loads(body, use_builtin_types=True)
    except Exception:
        return None
    return (method, params) if method is not None else None


@given(st.sampled_from(["lookupNode", "registerPublisher", "system.multicall"]), st.lists(scalars, max_size=5))
def test_stdlib_encoded_calls_decode_identically_or_fall_back(method: str, params: list[Any]) -> None:
    body = xmlrpc.client.dumps(tuple(params), method).encode()
    fast = fast_decode_call(body)
    assert fast is None or fast == stdlib(body)
    if all(isinstance(p, str) and p.isascii() and p.isprintable() and not set(p) & set("<>&]") for p in params):
        assert fast == (method, tuple(params))


@given(st.lists(st.text(alphabet="abc/_ \t\n:", max_size=6), max_size=4))
def test_untyped_string_values_as_roscpp_sends_them_decode_like_the_stdlib(params: list[str]) -> None:
    inner = "".join(f"<param><value>{p}</value></param>" for p in params)
    body = f"<?xml version='1.0'?>\n<methodCall><methodName>getPid</methodName><params>{inner}</params></methodCall>"
    fast = fast_decode_call(body.encode())
    assert fast is not None
    assert fast == stdlib(body.encode())


@settings(max_examples=300)
@given(st.lists(scalars, max_size=3), st.integers(0, 400), st.binary(min_size=1, max_size=4))
def test_corrupted_bodies_are_never_accepted_differently(params: list[Any], at: int, junk: bytes) -> None:
    body = xmlrpc.client.dumps(tuple(params), "getParam").encode()
    at %= len(body) + 1
    mutated = body[:at] + junk + body[at:]
    fast = fast_decode_call(mutated)
    if fast is not None:
        assert fast == stdlib(mutated)


replies = st.recursive(
    st.one_of(st.text(max_size=8), st.integers(-(2**32), 2**32), st.booleans(), st.floats(), st.none()),
    lambda inner: st.lists(inner, max_size=3) | st.tuples(inner, inner) | st.dictionaries(st.text(max_size=2), inner),
    max_leaves=8,
)


@given(replies)
def test_fast_response_encoding_is_byte_identical_to_the_stdlib(value: Any) -> None:
    fast = fast_encode_response(value)
    if fast is not None:
        assert fast == encode_response(value)


# --- the fast path accepts exactly what the full decoder accepts ---------------------------------------------


def full(body: bytes) -> tuple[str, tuple[Any, ...]] | None:
    """The full decoder alone (no fast path): what it returns, or None when it refuses."""
    from mrosd.xmlrpc.codec import _checked_call, _loads

    try:
        return _checked_call(_loads(body))
    except Exception:
        return None


def agree(body: bytes) -> None:
    fast = fast_decode_call(body)
    if fast is not None:
        assert fast == full(body), body
    try:
        combined: tuple[str, tuple[Any, ...]] | None = decode_call(body)
    except RemoteProtocolError:
        combined = None
    assert combined == full(body), body


TAGS = [b"i4", b"int", b"string", b"boolean", b"value", b"param", b"params", b"methodName", b"methodCall", b"double"]


@st.composite
def tag_swapped(draw: st.DrawFn) -> bytes:
    """A fast-path-shaped call with one closing (or opening) tag renamed: ``<i4>5</int>`` and the like."""
    params = draw(st.lists(st.one_of(st.integers(-(2**31), 2**31 - 1), st.booleans(), st.text("ab /", max_size=4))))
    body = xmlrpc.client.dumps(tuple(params), "getParam").encode()
    body = body.replace(b"<int>", draw(st.sampled_from([b"<int>", b"<i4>"])), 1)
    old = draw(st.sampled_from(TAGS))
    new = draw(st.sampled_from(TAGS))
    closing = draw(st.booleans())
    pattern = b"</%s>" % old if closing else b"<%s>" % old
    return body.replace(pattern, b"</%s>" % new if closing else b"<%s>" % new, 1)


@settings(max_examples=300)
@given(tag_swapped())
def test_mismatched_tags_are_refused_by_both_paths(body: bytes) -> None:
    agree(body)


def test_the_mismatched_tags_that_the_fast_path_once_accepted_are_refused() -> None:
    for body in (
        b"<methodCall><methodName>f</methodName><params><param><value><i4>5</int></value></param></params></methodCall>",
        b"<methodCall><methodName>f</methodName><params><param><value><int>5</i4></value></param></params></methodCall>",
    ):
        assert fast_decode_call(body) is None
        with pytest.raises(RemoteProtocolError, match="mismatched tag"):
            decode_call(body)


def test_a_carriage_return_in_text_is_decoded_as_xml_says_a_line_feed() -> None:
    body = (
        b"<methodCall><methodName>f</methodName><params><param><value>a\r\nb\rc</value></param></params></methodCall>"
    )
    assert decode_call(body) == ("f", ("a\nb\nc",))
    agree(body)


@settings(max_examples=500)
@given(
    st.one_of(
        st.binary(max_size=300),
        st.builds(
            lambda m, p: encode_call(m, tuple(p)),
            st.sampled_from(["getPid", "registerPublisher", "a.b"]),
            st.lists(scalars, max_size=4),
        ),
    ),
    st.lists(
        st.tuples(st.integers(0, 400), st.sampled_from([b"", b"<", b"&", b"\r", b"<!--x-->", b"&amp;", b" "])),
        max_size=3,
    ),
)
def test_any_input_decodes_the_same_on_both_paths_or_is_refused_by_both(
    body: bytes, edits: list[tuple[int, bytes]]
) -> None:
    for offset, junk in edits:
        at = offset % (len(body) + 1)
        body = body[:at] + junk + body[at:]
    agree(body)


# --- DTDs and entities are refused outright -----------------------------------------------------------------

CALL = "<methodCall><methodName>getParam</methodName><params><param><value>{}</value></param></params></methodCall>"
DTD_BODIES = {
    "internal entity": '<?xml version="1.0"?><!DOCTYPE m [<!ENTITY e "boom">]>' + CALL.format("&e;"),
    "doctype without entities": "<!DOCTYPE methodCall>" + CALL.format("x"),
    "external entity": '<!DOCTYPE m [<!ENTITY e SYSTEM "file:///etc/passwd">]>' + CALL.format("&e;"),
    "parameter entity": '<!DOCTYPE m [<!ENTITY % p SYSTEM "http://127.0.0.1:1/x.dtd"> %p;]>' + CALL.format("x"),
    "external dtd": '<!DOCTYPE m SYSTEM "http://127.0.0.1:1/x.dtd">' + CALL.format("x"),
    "undeclared entity": CALL.format("&e;"),
}


@pytest.mark.parametrize("name", sorted(DTD_BODIES))
async def test_dtds_and_entities_are_refused_with_a_one_line_error(name: str) -> None:
    body = DTD_BODIES[name].encode()
    assert fast_decode_call(body) is None
    for decode in (decode_call, decode_response):
        with pytest.raises(RemoteProtocolError) as info:
            decode(body)
        assert "\n" not in str(info.value) and len(str(info.value)) < 400
    padded = body.replace(b"<methodCall>", b"<methodCall>" + b" " * INCREMENTAL_DECODE_SIZE)
    with pytest.raises(RemoteProtocolError):
        await decode_call_async(padded)


def test_predefined_and_numeric_character_references_still_decode() -> None:
    body = CALL.format("&lt;&gt;&amp;&quot;&apos;&#65;&#x42;").encode()
    assert decode_call(body) == ("getParam", ("<>&\"'AB",))


def test_a_fault_reply_with_a_dtd_is_refused_not_raised_as_a_fault() -> None:
    fault = xmlrpc.client.dumps(xmlrpc.client.Fault(1, "x"), methodresponse=True)
    with pytest.raises(RemoteProtocolError):
        decode_response(('<!DOCTYPE m [<!ENTITY e "x">]>' + fault).encode())
    with pytest.raises(Fault):
        decode_response(fault.encode())


async def test_a_body_decoded_in_slices_gives_what_the_one_shot_decoder_gives() -> None:
    params = (["x" * 100, 7, {"k": [1.5, True]}],) * 2000
    body = encode_call("setParam", params)
    assert len(body) > 2 * INCREMENTAL_DECODE_SIZE
    assert await decode_call_async(body) == decode_call(body) == ("setParam", params)
    with pytest.raises(RemoteProtocolError):
        await decode_call_async(body[:-20])
