"""The wire layout of a message type, walked once: what the generator sizes and what a body is checked against.

``Layouts(lookup).of(spec)`` walks a type's fields (nested types inlined, consecutive fixed-size runs merged)
into a ``Layout``: its steps over a serialized body and its size when every field has a fixed size. The code
generator takes each class's ``_fixed_size`` from it (``mrosd.msg.codegen.sizes.fixed_size``), and
``Layout.check`` walks a body along the steps without building a message: each string's and each variable
array's length prefix is read and checked against what is left, fixed-size runs are skipped in one step, and
the walk must end at the body's last byte. It agrees with the generated deserializer on every body (the fleet
checks what another robot sends with it, ``mrosd.fleet.check``: a TFMessage of 100 transforms costs the
deserializer about 1 ms, this a small fraction). Strings are not decoded (rospy and roscpp accept any bytes
there; rospy replaces what is not UTF-8).

Pure: specs in, steps out; bytes in, None or ``DeserializationError`` out. Must not know classes or I/O.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mrosd.errors import DeserializationError, MsgNotFoundError, MsgTooComplexError
from mrosd.msg.bounds import MAX_DEPTH
from mrosd.msg.parser import parse_definition
from mrosd.msg.spec import PRIMITIVE_FORMATS, MsgSpec

__all__ = ["Layout", "Layouts", "builtin_size", "class_layout"]

Lookup = Callable[[str], MsgSpec]

_U32 = struct.Struct("<I")

#: Bound on the item count of an array of messages that occupy no bytes (an empty message type): nothing in
#: the buffer limits such a count, so without it a forged header could spin for hours. The generated
#: deserializer refuses a larger count too (``mrosd.msg.codegen.decode``), and the walk must agree with it.
MAX_EMPTY_ITEMS = 1 << 16

# Steps are (op, argument) tuples, not Structs: the check runs one per field of every body the fleet receives.
#: ``(_FIXED, size)``: skip ``size`` bytes
_FIXED = 0
#: ``(_STRING, None)``: one length-prefixed string
_STRING = 1
#: ``(_ITEMS, size)``: a count, then that many items of ``size`` bytes (primitives or fixed-size messages)
_ITEMS = 2
#: ``(_STRINGS, None)``: a count, then that many strings
_STRINGS = 3
#: ``(_STRINGS_N, n)``: ``n`` strings (``string[n]``)
_STRINGS_N = 4
#: ``(_MESSAGES, steps)``: a count, then that many messages of variable size
_MESSAGES = 5
#: ``(_MESSAGES_N, (steps, n))``: ``n`` messages of variable size
_MESSAGES_N = 6

Steps = list[tuple[int, Any]]


def builtin_size(base: str) -> int | None:
    """The wire size of a fixed-size builtin type (primitives, ``time``, ``duration``); None for any other."""
    if base in PRIMITIVE_FORMATS:
        return PRIMITIVE_FORMATS[base][1]
    if base in ("time", "duration"):
        return 8
    return None


class _Malformed(Exception):
    """Raised inside the walk; ``Layout.check`` names the type and makes it a ``DeserializationError``."""


@dataclass(frozen=True, slots=True)
class Layout:
    """The steps of one message type over its serialized body, and its size when that is fixed."""

    type: str
    steps: Steps
    #: the size of every body of the type, or None when strings or variable arrays make it vary
    fixed: int | None

    def check(self, body: bytes | bytearray | memoryview) -> None:
        """Return when ``body`` is exactly one well-formed message of the type.

        Raises:
            DeserializationError: a length prefix or a field past the end, or bytes after the message (one
                line naming the type and the byte offset: the peer sent it, nothing to fix here).
        """
        n = len(body)
        if self.fixed is not None:
            if n != self.fixed:
                raise DeserializationError(f"{self.type}: {n} bytes, the type has exactly {self.fixed}")
            return
        try:
            end = _walk(self.steps, body, 0, n)
        except _Malformed as exc:
            raise DeserializationError(f"{self.type}: {exc}") from None
        if end != n:
            raise DeserializationError(f"{self.type}: {n - end} trailing bytes after a {end}-byte message")


class Layouts:
    """Layouts of the types one lookup resolves, each type walked once."""

    def __init__(self, lookup: Lookup) -> None:
        self.lookup = lookup
        self._done: dict[str, Layout] = {}

    def of(self, spec: MsgSpec, _depth: int = 0) -> Layout:
        """The layout of ``spec`` (its nested types through the lookup).

        Raises:
            MsgTooComplexError: types nested deeper than ``MAX_DEPTH`` (a type that contains itself).
            MsgError: the lookup cannot resolve a nested type.
        """
        name = spec.full_name
        done = self._done.get(name)
        if done is not None:
            return done
        if _depth > MAX_DEPTH:
            raise MsgTooComplexError(f"{name}: message types nested deeper than {MAX_DEPTH}")
        steps: Steps = []
        for f in spec.fields:
            size = builtin_size(f.base)
            count = f.length
            if f.base == "string":
                if not f.is_array:
                    steps.append((_STRING, None))
                else:
                    steps.append((_STRINGS, None) if count is None else (_STRINGS_N, count))
                continue
            if size is None:  # a nested message
                sub = self._done.get(f.base) or self.of(self.lookup(f.base), _depth + 1)
                if sub.fixed is None:
                    if not f.is_array:
                        steps.extend(sub.steps)  # its steps are the parent's (no call per field)
                    else:
                        steps.append((_MESSAGES, sub.steps) if count is None else (_MESSAGES_N, (sub.steps, count)))
                    continue
                size = sub.fixed
            if not f.is_array:
                steps.append((_FIXED, size))
            elif count is None:
                steps.append((_ITEMS, size))
            else:
                steps.append((_FIXED, size * count))
        merged: Steps = []
        for step in steps:  # consecutive fixed-size runs are one step
            if step[0] == _FIXED and merged and merged[-1][0] == _FIXED:
                merged[-1] = (_FIXED, merged[-1][1] + step[1])
            elif step != (_FIXED, 0):
                merged.append(step)
        fixed = None
        if not merged:
            fixed = 0
        elif len(merged) == 1 and merged[0][0] == _FIXED:
            fixed = merged[0][1]
        layout = self._done[name] = Layout(name, merged, fixed)
        return layout


def class_layout(cls: Any, fallback: Lookup | None = None) -> Layout:
    """The layout of a generated message class, from the definition it was built from (``_full_text``).

    A class built from a peer's definition (``load_type``) may leave out types the search path defines: those
    come from ``fallback``, as they did when the class was built (the caller's typestore's ``msg_spec``).

    Raises:
        MsgError: the definition does not parse, uses a type neither it nor ``fallback`` defines, or nests
            deeper than ``MAX_DEPTH``.
    """
    name = str(cls._type)
    specs = parse_definition(name, str(cls._full_text))

    def lookup(nested: str) -> MsgSpec:
        spec = specs.get(nested)
        if spec is not None:
            return spec
        if fallback is None:
            raise MsgNotFoundError(f"{name}: its definition does not define {nested}")
        return fallback(nested)

    return Layouts(lookup).of(specs[name])


def _count(buf: Any, off: int, n: int, each: int) -> tuple[int, int]:
    """An array's length prefix at ``off``: (count, offset after it); the elements must fit what is left."""
    if off + 4 > n:
        raise _Malformed(f"an array's length prefix at byte {off} is past the end ({n} bytes)")
    (count,) = _U32.unpack_from(buf, off)
    off += 4
    if not each:
        if count > MAX_EMPTY_ITEMS:
            raise _Malformed(f"an array of {count} empty messages at byte {off}: at most {MAX_EMPTY_ITEMS}")
    elif count * each > n - off:
        raise _Malformed(f"an array of {count} at byte {off} needs more than the {n - off} bytes left")
    return count, off


def _walk(steps: Steps, buf: Any, off: int, n: int) -> int:
    for op, arg in steps:
        if op == _FIXED:
            off += arg
        elif op == _STRING:  # inline, not a call: the most frequent step of a variable-size type
            if off + 4 > n:
                raise _Malformed(f"a string's length prefix at byte {off} is past the end ({n} bytes)")
            off += 4 + _U32.unpack_from(buf, off)[0]
        elif op == _ITEMS:
            count, off = _count(buf, off, n, arg)
            off += count * arg
        elif op == _MESSAGES:
            count, off = _count(buf, off, n, 1)
            for _ in range(count):
                off = _walk(arg, buf, off, n)
        elif op == _MESSAGES_N:
            sub, count = arg
            for _ in range(count):
                off = _walk(sub, buf, off, n)
        else:  # _STRINGS, _STRINGS_N
            if op == _STRINGS:
                count, off = _count(buf, off, n, 4)
            else:
                count = arg
            for _ in range(count):
                if off + 4 > n:
                    raise _Malformed(f"a string's length prefix at byte {off} is past the end ({n} bytes)")
                off += 4 + _U32.unpack_from(buf, off)[0]
        if off > n:
            raise _Malformed(f"a field ends at byte {off}, past the end ({n} bytes)")
    return off
