"""Encoding one big XML-RPC value a chunk at a time: ``ValueEncoder`` and the reply prefix and suffix around it.

Owns the cut of a value's ``<value>...</value>`` into bytes chunks of about ``VALUE_CHUNK``, so that an event
loop can run between chunks and a value encoded once can be spliced into many replies without a join. The
bytes are the stdlib Marshaller's (property-tested). Must not know who sends the chunks (the master's HTTP
layer does) nor any decoding. Pure: no I/O.
"""

from __future__ import annotations

import xmlrpc.client
from collections.abc import Iterator
from typing import Any

from mrosd.errors import LocalProtocolError
from mrosd.xmlrpc.fastpath import ESCAPE_SLICE, INT_MAX, INT_MIN, RESPONSE_HEAD, RESPONSE_TAIL, dump_simple, escape

_PARAMS_HEAD = "<params>\n<param>\n"
_PARAMS_TAIL = "</param>\n</params>\n"

#: ``encode_value_chunks`` cuts its output into bytes objects of about this size.
VALUE_CHUNK = 256 * 1024


class _OverLimit(Exception):
    """Raised inside ``_ChunkWriter`` once its output passed its limit: the rest is not encoded."""


class _ChunkWriter:
    """Collects text pieces into bytes chunks of about ``VALUE_CHUNK``: no single join or copy of a whole value."""

    __slots__ = ("_limit", "_pending", "_size", "chunks", "total")

    def __init__(self, limit: int | None) -> None:
        self.chunks: list[bytes] = []
        self.total = 0
        self._limit = limit
        self._pending: list[str] = []
        self._size = 0

    def write(self, text: str) -> bool:
        """Add a piece; True when that completed a chunk (a good moment to let other work run)."""
        self._pending.append(text)
        self._size += len(text)
        if self._size >= VALUE_CHUNK:
            self.flush()
            return True
        return False

    def flush(self) -> None:
        if self._pending:
            chunk = "".join(self._pending).encode()
            self.chunks.append(chunk)
            self.total += len(chunk)
            self._pending = []
            self._size = 0
            if self._limit is not None and self.total > self._limit:
                raise _OverLimit


def _write_value(value: Any, w: _ChunkWriter) -> Iterator[None]:
    """The stdlib Marshaller's output for ``value``, piece by piece (its own code for any other type); yields
    after each completed chunk."""
    kind = type(value)
    if kind is str:
        if w.write("<value><string>"):
            yield
        for i in range(0, len(value), ESCAPE_SLICE):
            if w.write(escape(value[i : i + ESCAPE_SLICE])):
                yield
        if w.write("</string></value>\n"):
            yield
    elif kind is bool:
        if w.write(f"<value><boolean>{int(value)}</boolean></value>\n"):
            yield
    elif kind is int:
        if not INT_MIN <= value <= INT_MAX:
            raise OverflowError("int exceeds XML-RPC limits")
        if w.write(f"<value><int>{value}</int></value>\n"):
            yield
    elif kind is float:
        if w.write(f"<value><double>{value!r}</double></value>\n"):
            yield
    elif value is None:
        if w.write("<value><nil/></value>"):
            yield
    elif kind is list or kind is tuple:
        w.write("<value><array><data>\n")
        for item in value:
            yield from _write_value(item, w)
        if w.write("</data></array></value>\n"):
            yield
    elif kind is dict:
        w.write("<value><struct>\n")
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError("dictionary key must be string")
            w.write(f"<member>\n<name>{escape(key)}</name>\n")
            yield from _write_value(item, w)
            if w.write("</member>\n"):
                yield
        if w.write("</struct></value>\n"):
            yield
    else:  # bytes, datetime, Binary, subclasses: the stdlib's own rules
        text = xmlrpc.client.dumps((value,), allow_none=True)
        if w.write(text[len(_PARAMS_HEAD) : len(text) - len(_PARAMS_TAIL)]):
            yield


class ValueEncoder:
    """Encodes one value a chunk per ``step()``, so an event loop can run other work in between.

    The result is the value's ``<value>...</value>`` exactly as the stdlib writes it inside any reply, as
    ``chunks`` of about ``VALUE_CHUNK`` bytes (``size`` in all): a big value encoded once and spliced into the
    replies of many callers (``reply_parts``) is never joined or copied whole. Past ``limit`` bytes encoding
    stops with ``over_limit`` set (memory never follows a value further).
    """

    __slots__ = ("_steps", "_writer", "over_limit")

    def __init__(self, value: Any, limit: int | None = None) -> None:
        self._writer = _ChunkWriter(limit)
        self._steps = _write_value(value, self._writer)
        self.over_limit = False

    @property
    def chunks(self) -> list[bytes]:
        return self._writer.chunks

    @property
    def size(self) -> int:
        return self._writer.total

    def step(self) -> bool:
        """Encode about one more chunk; False once done (or over the limit).

        Raises:
            LocalProtocolError: the value cannot be represented in XML-RPC.
            RuntimeError: a dict or list of the value changed size while it was being encoded.
        """
        try:
            next(self._steps)
            return True
        except StopIteration:
            self._writer.flush()
        except _OverLimit:
            self.over_limit = True
            self._writer.chunks.clear()
        except (OverflowError, TypeError, RecursionError) as exc:
            raise LocalProtocolError(f"cannot encode XML-RPC response: {exc}") from exc
        return False


def encode_value_chunks(value: Any, limit: int | None = None) -> tuple[list[bytes], int]:
    """``ValueEncoder`` run to the end: ``(chunks, size)``; past ``limit``, ``([], size so far)``.

    Raises:
        LocalProtocolError: the value cannot be represented in XML-RPC.
    """
    encoder = ValueEncoder(value, limit)
    while encoder.step():
        pass
    return encoder.chunks, encoder.size


def response_parts() -> tuple[bytes, bytes]:
    """``(prefix, suffix)``: ``prefix + b"".join(encode_value_chunks(v)[0]) + suffix`` is ``encode_response(v)``."""
    return RESPONSE_HEAD.encode(), RESPONSE_TAIL.encode()


def reply_parts(code: int, status: str) -> tuple[bytes, bytes]:
    """``(prefix, suffix)``: ``prefix + b"".join(encode_value_chunks(v)[0]) + suffix`` is
    ``encode_response([code, status, v])``."""
    head = [RESPONSE_HEAD, "<value><array><data>\n"]
    if not (dump_simple(code, head) and dump_simple(status, head)):
        raise LocalProtocolError(f"cannot encode reply status {code!r}, {status!r}")
    return "".join(head).encode(), ("</data></array></value>\n" + RESPONSE_TAIL).encode()
