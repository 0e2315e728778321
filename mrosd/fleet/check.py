"""The fleet's check of a serialized ROS 1 body against its type, without decoding it.

Every body received over Zenoh must be exactly one well-formed message of its type before a ROS node sees
it (rospy drops the connection on a bad frame). The walk is the message package's one
(``mrosd.msg.layout``: lengths, bounds, the exact size, no objects built); this module gives the fleet its
verdict as a line to log and count rather than an exception.

``body_checker(cls)`` walks a generated class's layout once (in a worker thread: it parses the class's
definition and may read the search path's); ``Checker.check(body)`` returns None or why the body is malformed.
"""

from __future__ import annotations

from typing import Any

from mrosd.errors import DeserializationError
from mrosd.msg.layout import Layout, class_layout
from mrosd.msg.loader import default_store

__all__ = ["Checker", "body_checker"]


class Checker:
    """Checks bodies of one type; made by ``body_checker``."""

    __slots__ = ("_layout", "type")

    def __init__(self, layout: Layout) -> None:
        self.type = layout.type
        self._layout = layout

    def check(self, body: bytes | bytearray | memoryview) -> str | None:
        """None when ``body`` is exactly one well-formed message of the type; else why not (one line)."""
        try:
            self._layout.check(body)
        except DeserializationError as exc:
            return str(exc)
        return None


def body_checker(cls: Any) -> Checker:
    """The checker of a generated message class (parses its definition, may read the search path's: call it
    off the event loop).

    Raises:
        MsgError: the class's definition does not parse, uses a type not on the search path, or nests too deep.
    """
    return Checker(class_layout(cls, default_store().msg_spec))
