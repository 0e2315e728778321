"""The XML-RPC fast path: the Master API's usual calls decoded by one regex, simple replies written directly.

Owns the shapes it accepts (ASCII strings, 32-bit ints, booleans, nested lists of them) and the exact bytes
the stdlib writes for them; ``mrosd.xmlrpc.chunks`` writes bigger values with the same primitives. Must not
know the full decoder: anything it does not match returns None, and ``mrosd.xmlrpc.codec`` decides.
Pure: no I/O.
"""

from __future__ import annotations

import re
from typing import Any

# Profiling showed expat parser construction dominating the master's CPU per call. Nearly every Master
# API call carries only short ASCII strings, so those exact shapes are matched here; anything else
# (other types, entities, CDATA, comments, DTDs, non-ASCII, CR, odd whitespace) returns None and goes
# through the full decoder. Property tests check the fast path never accepts what the full decoder
# refuses and never decodes differently.

_WS = rb"[ \t\n\r]*"
# Printable ASCII and tab/LF, without < & ] (markup) and CR (expat turns CR and CRLF into LF).
_TEXT = rb"[\t\n\x20-\x25\x27-\x3b\x3d-\x5c\x5e-\x7e]*"
# Every run of whitespace is followed by a literal ``<`` (which it cannot contain), so a failing match
# backtracks linearly, never exponentially.


def _one_param(group: bytes) -> bytes:
    """One parameter and the whitespace after it; ``group`` opens the value groups (capturing or not)."""
    return (
        rb"<param>" + _WS + rb"<value>(?:<string>" + group + _TEXT + rb")</string>"
        rb"|<i4>" + group + rb"[-+]?[0-9]{1,9})</i4>"
        rb"|<int>" + group + rb"[-+]?[0-9]{1,9})</int>"
        rb"|<boolean>" + group + rb"[01])</boolean>|" + group + _TEXT + rb"))</value>" + _WS + rb"</param>" + _WS
    )


_CALL = re.compile(
    rb"(?:<\?xml version=(?:'1\.0'|\"1\.0\")(?: encoding=(?:'(?i:utf-8)'|\"(?i:utf-8)\"))?\?>)?"
    + _WS
    + rb"<methodCall>"
    + _WS
    + rb"<methodName>([A-Za-z0-9_.]{1,200})</methodName>"
    + _WS
    + rb"(?:<params>"
    + _WS
    + rb"((?:"
    + _one_param(b"(?:")
    + rb")*)</params>"
    + _WS
    + rb"|<params/>"
    + _WS
    + rb")?</methodCall>"
    + _WS,
    re.S,
)
_PARAM = re.compile(_one_param(b"("))


def fast_decode_call(body: bytes) -> tuple[str, tuple[Any, ...]] | None:
    """Decode a methodCall made only of ASCII strings, ints and booleans; None for anything else.

    One regex validates the whole call; ``findall`` then walks the (already validated) parameters.
    """
    call = _CALL.fullmatch(body)
    if call is None:
        return None
    text = call.group(2)
    if not text:
        return call.group(1).decode(), ()
    params: list[Any] = []
    for s, i4, i, b, untyped in _PARAM.findall(text):
        if i4 or i:
            params.append(int(i4 or i))
        elif b:
            params.append(b == b"1")
        else:  # <string> or untyped text (an empty string leaves both groups empty)
            params.append((s or untyped).decode())
    return call.group(1).decode(), tuple(params)


RESPONSE_HEAD = "<?xml version='1.0'?>\n<methodResponse>\n<params>\n<param>\n"
RESPONSE_TAIL = "</param>\n</params>\n</methodResponse>\n"
INT_MIN, INT_MAX = -(2**31), 2**31 - 1


def escape(text: str) -> str:
    if "&" in text:
        text = text.replace("&", "&amp;")
    if "<" in text:
        text = text.replace("<", "&lt;")
    if ">" in text:
        text = text.replace(">", "&gt;")
    return text


#: Strings longer than this are escaped slice by slice: a thread encoding a 100 MB value then holds the GIL
#: for one slice at a time, not for a whole-string ``replace`` (escaping is per character, so slices agree).
ESCAPE_SLICE = 256 * 1024


def dump_simple(value: Any, out: list[str]) -> bool:
    if isinstance(value, str):
        if len(value) > ESCAPE_SLICE:
            out.append("<value><string>")
            out.extend(escape(value[i : i + ESCAPE_SLICE]) for i in range(0, len(value), ESCAPE_SLICE))
            out.append("</string></value>\n")
            return True
        out.append(f"<value><string>{escape(value)}</string></value>\n")
    elif value is True or value is False:
        out.append(f"<value><boolean>{int(value)}</boolean></value>\n")
    elif type(value) is int:
        if not INT_MIN <= value <= INT_MAX:
            return False
        out.append(f"<value><int>{value}</int></value>\n")
    elif type(value) is list or type(value) is tuple:
        out.append("<value><array><data>\n")
        for item in value:
            if not dump_simple(item, out):
                return False
        out.append("</data></array></value>\n")
    else:
        return False
    return True


def fast_encode_response(value: Any) -> bytes | None:
    """The stdlib's exact response bytes for strings, ints, booleans and (nested) lists; None otherwise."""
    out = [RESPONSE_HEAD]
    try:
        if not dump_simple(value, out):
            return None
    except RecursionError:
        return None
    out.append(RESPONSE_TAIL)
    return "".join(out).encode()
