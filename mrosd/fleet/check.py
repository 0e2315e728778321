"""Check a serialized ROS 1 body against its type without decoding it: lengths, bounds, the exact size.

Every body received over Zenoh must be exactly one well-formed message of its type before a ROS node sees
it (rospy drops the connection on a bad frame). The generated deserializer checks that, but builds every
object on the way: a TFMessage of 100 transforms costs about 1 ms. This walks the same wire layout and only
moves an offset: each string's and each variable array's length prefix is read and checked against what is
left, fixed-size runs are skipped in one step, and the walk must end at the body's last byte. Strings are not
decoded (rospy and roscpp accept any bytes there; rospy replaces what is not UTF-8).

``body_checker(cls)`` compiles the walk for a generated class once (in a worker thread: it loads the nested
classes); ``Checker.check(body)`` returns None or why the body is malformed.
"""

from __future__ import annotations

import re
import struct
from typing import Any

from mrosd.msg import get_message_class
from mrosd.msg.spec import PRIMITIVE_FORMATS

__all__ = ["Checker", "body_checker"]

_U32 = struct.Struct("<I")
#: Nested message types at most along one path (genmsg types are not recursive; this bounds a hostile one).
MAX_DEPTH = 32
_ARRAY = re.compile(r"^(?P<base>[^\[\]]+)(\[(?P<len>\d*)\])?$")

# Walk operations: (op, argument).
_FIXED, _STRING, _PRIM_ARRAY, _STR_ARRAY, _MSG_ARRAY, _MSG_FIXED_ARRAY, _STR_FIXED_ARRAY = range(7)

Plan = list[tuple[int, Any]]


class _Malformed(Exception):
    pass


def _size_of(base: str) -> int | None:
    if base in PRIMITIVE_FORMATS:
        return PRIMITIVE_FORMATS[base][1]
    if base in ("time", "duration"):
        return 8
    return None


class _Compiler:
    def __init__(self) -> None:
        #: type name -> (plan, fixed size or None)
        self.done: dict[str, tuple[Plan, int | None]] = {}

    def compile(self, cls: Any, depth: int = 0) -> tuple[Plan, int | None]:
        name = str(cls._type)
        known = self.done.get(name)
        if known is not None:
            return known
        if depth > MAX_DEPTH:
            raise ValueError(f"{name}: nested more than {MAX_DEPTH} deep")
        plan: Plan = []
        fixed: int | None = 0
        for slot in cls._slot_types:
            m = _ARRAY.match(slot)
            if m is None:
                raise ValueError(f"{name}: field type {slot!r} not understood")
            base, length = m["base"], m["len"]
            is_array, count = length is not None, int(length) if length else None
            size = _size_of(base)
            if base == "string":
                if not is_array:
                    plan.append((_STRING, None))
                elif count is None:
                    plan.append((_STR_ARRAY, None))
                else:
                    plan.append((_STR_FIXED_ARRAY, count))
                fixed = None
            elif size is not None:
                if not is_array:
                    plan.append((_FIXED, size))
                elif count is None:
                    plan.append((_PRIM_ARRAY, size))
                    fixed = None
                else:
                    plan.append((_FIXED, size * count))
            else:
                sub_plan, sub_fixed = self.compile(get_message_class(base), depth + 1)
                if not is_array:  # a nested message's steps are the parent's (no call per field)
                    plan.extend([(_FIXED, sub_fixed)] if sub_fixed is not None else sub_plan)
                elif count is None:
                    plan.append((_PRIM_ARRAY, sub_fixed) if sub_fixed is not None else (_MSG_ARRAY, sub_plan))
                    fixed = None
                elif sub_fixed is not None:
                    plan.append((_FIXED, sub_fixed * count))
                else:
                    plan.append((_MSG_FIXED_ARRAY, (sub_plan, count)))
                if sub_fixed is None:
                    fixed = None
            if fixed is not None and plan and plan[-1][0] == _FIXED:
                fixed += plan[-1][1]
        merged: Plan = []
        for op in plan:  # consecutive fixed-size runs are one step
            if op[0] == _FIXED and merged and merged[-1][0] == _FIXED:
                merged[-1] = (_FIXED, merged[-1][1] + op[1])
            elif op != (_FIXED, 0):
                merged.append(op)
        self.done[name] = (merged, fixed)
        return merged, fixed


def _count(buf: bytes, off: int, n: int, each: int) -> tuple[int, int]:
    """An array's length prefix at ``off``: (count, offset after it); the elements must fit what is left."""
    if off + 4 > n:
        raise _Malformed(f"an array's length prefix at byte {off} is past the end ({n} bytes)")
    (count,) = _U32.unpack_from(buf, off)
    off += 4
    if count * max(each, 1) > n - off:
        raise _Malformed(f"an array of {count} at byte {off} needs more than the {n - off} bytes left")
    return count, off


def _walk(plan: Plan, buf: bytes, off: int, n: int) -> int:
    for op, arg in plan:
        if op == _FIXED:
            off += arg
        elif op == _STRING:
            if off + 4 > n:
                raise _Malformed(f"a string's length prefix at byte {off} is past the end ({n} bytes)")
            off += 4 + _U32.unpack_from(buf, off)[0]
        elif op == _PRIM_ARRAY:
            count, off = _count(buf, off, n, arg)
            off += count * arg
        elif op == _MSG_ARRAY:
            count, off = _count(buf, off, n, 1)
            for _ in range(count):
                off = _walk(arg, buf, off, n)
        elif op == _MSG_FIXED_ARRAY:
            sub, count = arg
            for _ in range(count):
                off = _walk(sub, buf, off, n)
        else:  # _STR_ARRAY, _STR_FIXED_ARRAY
            if op == _STR_ARRAY:
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


class Checker:
    """Checks bodies of one type; made by ``body_checker``."""

    __slots__ = ("_fixed", "_plan", "type")

    def __init__(self, type_name: str, plan: Plan, fixed: int | None) -> None:
        self.type = type_name
        self._plan = plan
        self._fixed = fixed

    def check(self, body: bytes) -> str | None:
        """None when ``body`` is exactly one well-formed message of the type; else why not (one line)."""
        n = len(body)
        if self._fixed is not None:
            return None if n == self._fixed else f"{self.type}: {n} bytes, the type has exactly {self._fixed}"
        try:
            end = _walk(self._plan, body, 0, n)
        except _Malformed as exc:
            return f"{self.type}: {exc}"
        if end != n:
            return f"{self.type}: {n - end} trailing bytes after a {end}-byte message"
        return None


def body_checker(cls: Any) -> Checker:
    """The checker of a generated message class (loads nested classes: call it off the event loop).

    Raises:
        ValueError: a field type it does not understand, or nesting deeper than ``MAX_DEPTH``.
        MrosError: a nested type cannot be loaded.
    """
    plan, fixed = _Compiler().compile(cls)
    return Checker(str(cls._type), plan, fixed)
