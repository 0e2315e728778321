"""Depth bounds of the JSON values clients send (pure).

msgspec's JSON decoder recurses once per array or object and stops at Python's recursion limit with
``RecursionError``: ``decode_bounded`` turns that (and ``MemoryError``) into the protocol's refusal. A value
that does decode may still nest hundreds of levels, and it would be stored (a parameter, a service request)
where every later encoder recurses into it again: ``check_depth`` refuses anything deeper than ``MAX_DEPTH``
before it is used.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["MAX_DEPTH", "TooDeep", "check_depth", "decode_bounded"]

#: Arrays and objects one client value may nest. ROS messages nest a few levels (a
#: ``visualization_msgs/MarkerArray`` has 5 levels of objects and arrays); 64 leaves room for any real message
#: or parameter tree and keeps every recursive encoder far below Python's default limit of 1000 frames.
MAX_DEPTH = 64

T = TypeVar("T")


class TooDeep(ValueError):
    """A value nests deeper than allowed."""


def decode_bounded(decode: Callable[[Any], T], data: Any) -> T:
    """``decode(data)``, with the decoder's own recursion and memory failures raised as ``TooDeep``/``ValueError``
    (what a protocol answers as malformed input), never as ``RecursionError``/``MemoryError``."""
    try:
        return decode(data)
    except RecursionError:
        raise TooDeep(f"nested deeper than the decoder allows (at most {MAX_DEPTH} levels are accepted)") from None
    except MemoryError:
        raise ValueError(f"{len(data)} bytes decode to more than this process can hold") from None


def check_depth(value: Any, limit: int = MAX_DEPTH) -> None:
    """Raise ``TooDeep`` when ``value`` (decoded JSON) nests more than ``limit`` lists and dicts.

    Iterative (no recursion of its own); it looks at every element of every container once.
    """
    todo: list[tuple[Any, int]] = [(value, 0)]
    while todo:
        item, depth = todo.pop()
        if isinstance(item, dict):
            children: Any = item.values()
        elif isinstance(item, list):
            children = item
        else:
            continue
        depth += 1
        if depth > limit:
            raise TooDeep(f"nested more than {limit} levels deep")
        todo.extend((c, depth) for c in children if isinstance(c, dict | list))
