"""The master's fast XML-RPC call decoder agrees with the stdlib codec wherever it answers."""

from __future__ import annotations

import xmlrpc.client
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.master.httpserver import fast_decode_call

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
    return method, params


@given(st.sampled_from(["lookupNode", "registerPublisher", "system.multicall"]), st.lists(scalars, max_size=5))
def test_stdlib_encoded_calls_decode_identically_or_fall_back(method: str, params: list[Any]) -> None:
    body = xmlrpc.client.dumps(tuple(params), method).encode()
    fast = fast_decode_call(body)
    assert fast is None or fast == stdlib(body)
    if all(isinstance(p, str) and p.isascii() and p.isprintable() and not set(p) & set("<&]") for p in params):
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
    from mrosd.master.httpserver import fast_encode_response
    from mrosd.xmlrpc import encode_response

    fast = fast_encode_response(value)
    if fast is not None:
        assert fast == encode_response(value)
