"""The project's HTTP/1.1 framing rules, sans IO: request-head parsing, refusal texts, response bytes, and the
client's side (request heads, response-head parsing) for ``mrosd.xmlrpc.client``.

Pure functions of bytes (no sockets, no event loop), so they are tested and fuzzed on their own;
``mrosd.master.httpserver`` drives them over connections. Accepted: POST with one Content-Length,
keep-alive (HTTP/1.1 default, HTTP/1.0 with the header), ``Expect: 100-continue``. Refused with
``HttpRefused`` (the status and one-line text to send before closing): other methods (405), chunked
bodies (411), a repeated Content-Length or Content-Length with Transfer-Encoding (400, request
smuggling), bodies over ``MAX_BODY_SIZE`` (413), garbage (400), and any request a browser sent (403).
Header blocks over ``MAX_HEADER_SIZE`` are the caller's to refuse (431): it must stop buffering before a
block is complete.

**Browsers.** Any web page may POST to any address with ``fetch`` in ``no-cors`` mode and a ``text/plain``
body: no preflight, so the call is made even though the page cannot read the answer. Through the master a
page would set parameters or register a publisher whose node is on the attacker's machine (every subscriber
of that topic then connects to it and takes its messages); through a node's slave API it would redirect the
node's subscriptions or shut it down. No ROS client (rospy, roscpp, rosbridge, mrosd) sends ``Origin`` or
``Sec-Fetch-*``; a browser sends ``Origin`` with every POST (DNS rebinding included). So a request carrying
either is refused.
"""

from __future__ import annotations

import functools
import re

from mrosd.errors import HttpRefused, RemoteProtocolError
from mrosd.xmlrpc.codec import MAX_BODY_SIZE

#: Largest request line + headers accepted.
MAX_HEADER_SIZE = 64 * 1024

# Header fields, matched on the lower-cased header block (which starts with the line break).
_CONTENT_LENGTH = re.compile(rb"\r\ncontent-length:[ \t]*(?:([0-9]{1,12})[ \t]*(?=\r\n|$)|.*)")
_BAD_FIELD_NAME = re.compile(rb"\r\n[^:\r\n]*[ \t]:")  # whitespace in a name or before its colon, obs-fold
_CONNECTION = re.compile(rb"\r\nconnection:[ \t]*(close|keep-alive)[ \t]*(?=\r\n|$)")
_FROM_A_BROWSER = re.compile(rb"\r\n(?:origin|sec-fetch-[a-z]+):")

_REASONS = {
    400: b"Bad Request",
    403: b"Forbidden",
    405: b"Method Not Allowed",
    408: b"Request Timeout",
    411: b"Length Required",
    413: b"Payload Too Large",
    431: b"Request Header Fields Too Large",
    503: b"Service Unavailable",
}


def status_response(status: int, text: bytes) -> bytes:
    """A complete ``Connection: close`` response carrying a short plain-text reason."""
    return b"HTTP/1.1 %d %s\r\nContent-Type: text/plain\r\nContent-Length: %d\r\nConnection: close\r\n\r\n%s" % (
        status,
        _REASONS.get(status, b"Error"),
        len(text),
        text,
    )


#: The answer to ``Expect: 100-continue``, written once the head is accepted.
CONTINUE_RESPONSE = b"HTTP/1.1 100 Continue\r\n\r\n"

#: The head of a successful response whose body is written after it: ``OK_HEAD % (length, connection)``.
OK_HEAD = b"HTTP/1.1 200 OK\r\nContent-Type: text/xml\r\nContent-Length: %d\r\nConnection: %s\r\n\r\n"

#: A successful response: ``OK_RESPONSE % (len(body), b"keep-alive" or b"close", body)``.
OK_RESPONSE = b"HTTP/1.1 200 OK\r\nContent-Type: text/xml\r\nContent-Length: %d\r\nConnection: %s\r\n\r\n%s"


def parse_head(head: bytes) -> tuple[int, bool, bool]:
    """``(content_length, keep_alive, expect_continue)`` of a header block (without the blank line).

    A pure function of the bytes, so short header blocks are cached (``parse_short_head``):
    clients repeat the same headers call after call.

    Raises:
        HttpRefused: the status and text to answer with before closing.
    """
    line_end = head.find(b"\r\n")
    parts = (head if line_end < 0 else head[:line_end]).split()
    if len(parts) != 3 or not parts[2].startswith(b"HTTP/1."):
        raise HttpRefused(400, b"malformed request line\n")
    if parts[0] != b"POST":
        raise HttpRefused(405, b"only POST is supported\n")
    keep_alive = parts[2] != b"HTTP/1.0"
    length: int | None = None
    expect_continue = False
    fields = head[line_end:].lower() if line_end >= 0 else b""
    if fields:
        if _BAD_FIELD_NAME.search(fields):
            raise HttpRefused(400, b"malformed header field\n")
        if _FROM_A_BROWSER.search(fields):
            raise HttpRefused(403, b"a web page may not call ROS XML-RPC (the request carries Origin)\n")
        lengths = _CONTENT_LENGTH.findall(fields)
        if b"\r\ntransfer-encoding" in fields:
            if lengths:  # which one frames the body is what request smuggling plays on
                raise HttpRefused(400, b"Content-Length with Transfer-Encoding\n")
            raise HttpRefused(411, b"chunked bodies are not supported; send Content-Length\n")
        if len(lengths) > 1:
            raise HttpRefused(400, b"more than one Content-Length\n")
        if lengths:
            if not lengths[0]:
                raise HttpRefused(400, b"bad Content-Length\n")
            length = int(lengths[0])
        m = _CONNECTION.search(fields)
        if m is not None:
            keep_alive = m.group(1) == b"keep-alive"
        expect_continue = b"\r\nexpect:" in fields and b"100-continue" in fields
    if length is None:
        raise HttpRefused(411, b"Content-Length required\n")
    if length > MAX_BODY_SIZE:
        raise HttpRefused(413, b"request body too large\n")
    return length, keep_alive, expect_continue


#: Header blocks up to this size may go to ``parse_short_head``, ``parse_head`` with a cache of 256 entries.
CACHED_HEAD_SIZE = 1024
parse_short_head = functools.lru_cache(maxsize=256)(parse_head)


# --- the client's side ----------------------------------------------------------------------------------------

_TRANSFER_ENCODING = re.compile(rb"\r\ntransfer-encoding:[ \t]*([^\r\n]*?)[ \t]*(?=\r\n|$)")

#: The head of an XML-RPC request: ``REQUEST_HEAD % (path, host, len(body))``; the connection is kept alive.
REQUEST_HEAD = (
    b"POST %s HTTP/1.1\r\nHost: %s\r\nUser-Agent: mrosd\r\nContent-Type: text/xml\r\nContent-Length: %d\r\n\r\n"
)


def parse_response_head(head: bytes) -> tuple[int, int | None, bool, bool]:
    """``(status, content_length, keep_alive, chunked)`` of a response's header block (without the blank line).

    ``content_length`` is None when the body is chunked or runs to the end of the connection (then
    ``keep_alive`` is False). Refused as request smuggling is refused: a repeated Content-Length, or one with
    Transfer-Encoding.

    Raises:
        RemoteProtocolError: a malformed status line or header block.
    """
    line_end = head.find(b"\r\n")
    parts = (head if line_end < 0 else head[:line_end]).split(None, 2)
    if len(parts) < 2 or not parts[0].startswith(b"HTTP/1.") or len(parts[1]) != 3 or not parts[1].isdigit():
        raise RemoteProtocolError("malformed HTTP status line")
    status = int(parts[1])
    keep_alive = parts[0] != b"HTTP/1.0"
    length: int | None = None
    chunked = False
    fields = head[line_end:].lower() if line_end >= 0 else b""
    if fields:
        if _BAD_FIELD_NAME.search(fields):
            raise RemoteProtocolError("malformed HTTP header field")
        lengths = _CONTENT_LENGTH.findall(fields)
        codings = _TRANSFER_ENCODING.findall(fields)
        if codings:
            if lengths:
                raise RemoteProtocolError("HTTP response with Content-Length and Transfer-Encoding")
            if codings != [b"chunked"]:
                raise RemoteProtocolError(
                    f"unsupported Transfer-Encoding {b', '.join(codings).decode(errors='replace')}"
                )
            chunked = True
        if len(lengths) > 1:
            raise RemoteProtocolError("HTTP response with more than one Content-Length")
        if lengths:
            if not lengths[0]:
                raise RemoteProtocolError("bad Content-Length")
            length = int(lengths[0])
        m = _CONNECTION.search(fields)
        if m is not None:
            keep_alive = m.group(1) == b"keep-alive"
    if length is None and not chunked:
        keep_alive = False  # the body runs to the end of the connection
    return status, length, keep_alive, chunked
