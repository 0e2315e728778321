"""Bodies as the fleet forwards them (serialized, undecoded) and the real classes that check them.

What crosses is forwarded as is, but never unchecked: every body received over Zenoh (a topic's sample, a
latched body, a service request or response) is first checked against its type, which checks
every length prefix, array bound and string length and the exact consumed length (issue 31, case 4; the
walk of ``mrosd.fleet.check``, which agrees with the generated deserializer without building objects). So the
fleet crosses only types it can check: a type on this robot's search path whose md5 is the announced one.
Classes come from ``load_type_async`` and worker threads, never from the loop (a definition may be costly).
"""

from __future__ import annotations

import asyncio
import importlib
from typing import Any, ClassVar

from mrosd.errors import ConfigError, MrosError
from mrosd.fleet.check import Checker, body_checker
from mrosd.msg import get_service_class, load_type_async

__all__ = [
    "FleetTypeError",
    "RawBody",
    "checker",
    "message_class",
    "raw_message_class",
    "raw_service_class",
    "require_zenoh",
    "service_class",
]


class FleetTypeError(MrosError):
    """A type the fleet cannot check: not on the search path, or another md5 than the one announced."""


def require_zenoh() -> Any:
    """The ``zenoh`` module.

    Raises:
        ConfigError: eclipse-zenoh is not installed.
    """
    try:
        return importlib.import_module("zenoh")
    except ImportError:
        raise ConfigError(
            "the fleet part needs Eclipse Zenoh for Python: pip install 'mrosd[fleet]' (eclipse-zenoh>=1.10)"
        ) from None


class RawBody:
    """A serialized body carried as is: what the bridge forwards needs no decoding."""

    __slots__ = ("data",)
    _type: ClassVar[str] = "*"
    _md5sum: ClassVar[str] = "*"
    _full_text: ClassVar[str] = ""

    def __init__(self, data: bytes = b"") -> None:
        self.data = data

    def serialize(self) -> bytes:
        return self.data

    @classmethod
    def deserialize(cls, body: bytes | bytearray | memoryview) -> RawBody:
        return cls(bytes(body))


def raw_message_class(msg_type: str, md5sum: str, full_text: str = "") -> type[RawBody]:
    """A message class whose instances are bodies of ``msg_type`` (for ``Node.advertise``); ``full_text`` goes
    into the connection header for tools that decode from it (rosbag, mrosd itself)."""
    attrs = {"__slots__": (), "_type": msg_type, "_md5sum": md5sum, "_full_text": full_text}
    return type("Raw_" + msg_type.replace("/", "_"), (RawBody,), attrs)


def raw_service_class(srv_type: str, md5sum: str) -> type[Any]:
    """A service class whose requests and responses are bodies (for ``advertise_service``/``service_proxy``)."""
    req = type("RawRequest", (RawBody,), {"__slots__": (), "_type": srv_type + "Request", "_md5sum": md5sum})
    resp = type("RawResponse", (RawBody,), {"__slots__": (), "_type": srv_type + "Response", "_md5sum": md5sum})
    return type(
        "RawService",
        (),
        {"_type": srv_type, "_md5sum": md5sum, "_request_class": req, "_response_class": resp},
    )


def _same_md5(cls: Any, name: str, md5sum: str) -> Any:
    if md5sum not in ("", "*") and cls._md5sum != md5sum:
        raise FleetTypeError(f"{name}: announced md5 {md5sum} is not this robot's {cls._md5sum}")
    return cls


async def message_class(msg_type: str, md5sum: str = "") -> type[Any]:
    """The generated class of ``msg_type`` from the search path (off the loop), checked against ``md5sum``.

    Raises:
        FleetTypeError: the type is unknown here, malformed, or has another md5.
    """
    try:
        cls = await load_type_async(msg_type, "")
    except (MrosError, RecursionError, MemoryError) as exc:
        raise FleetTypeError(f"{msg_type}: cannot check its bodies: {exc}") from None
    return _same_md5(cls, msg_type, md5sum)  # type: ignore[no-any-return]


async def service_class(srv_type: str, md5sum: str = "") -> Any:
    """The generated service class of ``srv_type`` (made in a worker thread), checked against ``md5sum``.

    Raises:
        FleetTypeError: as ``message_class``.
    """
    try:
        cls = await asyncio.to_thread(get_service_class, srv_type)
    except (MrosError, RecursionError, MemoryError) as exc:
        raise FleetTypeError(f"{srv_type}: cannot check its requests: {exc}") from None
    return _same_md5(cls, srv_type, md5sum)


async def checker(cls: Any) -> Checker:
    """The body checker of a generated class (``mrosd.fleet.check``), compiled in a worker thread.

    Raises:
        FleetTypeError: a field type the checker does not understand, or a nested type that cannot be loaded.
    """
    try:
        return await asyncio.to_thread(body_checker, cls)
    except (MrosError, ValueError, RecursionError) as exc:
        raise FleetTypeError(f"{cls._type}: cannot check its bodies: {exc}") from None
