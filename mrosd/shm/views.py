"""Typed messages whose large arrays are read-only views into a shared-memory slot (pure: no descriptors).

The generated decoders copy what they cannot prove immutable (a view of a mapping is not ``bytes``), and
should: for them, memory that another process writes is never safe. A leased slot is: the publisher does
not write it until the lease ends (``mrosd.shm.publisher``). So a leased message is decoded by a variant of
the generated decoder made for this (``mrosd.msg.loader.view_decoder``, generated once per type at
subscribe time): the same flattened reads, with its uint8[]/char[] and numeric arrays of at least
``ZERO_COPY_MIN`` bytes left as read-only views of the slot, cast to their element type
(``np.frombuffer(msg.data, np.uint8)`` works on them, as on bytes). It replaced a walk of the type's field
list followed by a decode of a copy with the arrays cut out: a third of the time from a wake-up to the
callback (docs/shm.md).

The message is of a subclass of the requested type (``leased_class``): the same fields, ``_md5sum`` and
``serialize``, plus ``release()`` and ``with msg:``. Its lease (``_shm_lease``) ends when it is released or
dropped; after that its views are released (reading them raises ``ValueError``) unless something, e.g. a
numpy array, still exports them (then the lease ends when that goes: ``mrosd.shm.subscriber``).
``field_offset`` walks a body by the type's field list, for loans that lay a message out in place.
"""

from __future__ import annotations

import functools
import struct
from typing import Any

from mrosd.errors import LocalProtocolError
from mrosd.msg.loader import view_decoder

__all__ = ["decode_view", "field_offset", "leased_class", "prepare"]

#: wire size of each fixed-size builtin; ``None`` marks a string
_SIZES: dict[str, int | None] = {
    "bool": 1,
    "byte": 1,
    "char": 1,
    "int8": 1,
    "uint8": 1,
    "int16": 2,
    "uint16": 2,
    "int32": 4,
    "uint32": 4,
    "float32": 4,
    "int64": 8,
    "uint64": 8,
    "float64": 8,
    "time": 8,
    "duration": 8,
    "string": None,
}
_U32 = struct.Struct("<I")


class _NotViewable(Exception):
    """A field type this walker does not know (then the message is decoded by copy, as always)."""


@functools.cache
def _split(type_text: str) -> tuple[str, bool, int | None]:
    if type_text.endswith("]"):
        base, _, rest = type_text.partition("[")
        n = rest[:-1]
        return base, True, int(n) if n else None
    return type_text, False, None


class _Found(Exception):
    def __init__(self, at: int) -> None:
        self.at = at


def _walk(cls: Any, b: memoryview, at: int, *, resolve: Any, stop: str | None = None) -> int:
    """Where a message of ``cls`` starting at ``at`` in ``b`` ends; ``_Found`` at top-level field ``stop``."""
    for name, type_text in zip(cls.__struct_fields__, cls._field_types, strict=False):
        if name == stop:
            raise _Found(at)
        base, is_array, fixed = _split(type_text)
        if not is_array:
            if base in _SIZES:
                size = _SIZES[base]
                at = at + 4 + _U32.unpack_from(b, at)[0] if size is None else at + size
            else:
                at = _walk(resolve(base), b, at, resolve=resolve)
            continue
        if fixed is None:
            count = _U32.unpack_from(b, at)[0]
            at += 4
        else:
            count = fixed
        if base in _SIZES:
            size = _SIZES[base]
            if size is None:  # string[]
                for _ in range(count):
                    at += 4 + _U32.unpack_from(b, at)[0]
                continue
            at += count * size
            if at > len(b):
                raise struct.error("array beyond the message")
        else:
            sub = resolve(base)
            for _ in range(count):
                at = _walk(sub, b, at, resolve=resolve)
    return at


@functools.cache
def _resolve(package: str, name: str) -> Any:
    """The class of a nested type, once per name (a failure is not cached: raised each time)."""
    from mrosd.msg import get_message_class

    if name == "Header":
        name = "std_msgs/Header"
    elif "/" not in name:
        name = f"{package}/{name}"
    return get_message_class(name)


def _resolver(cls: Any) -> Any:
    package = cls._type.split("/")[0]

    def resolve(name: str) -> Any:
        try:
            return _resolve(package, name)
        except Exception as exc:  # any failure to resolve means: decode by copy
            raise _NotViewable(name) from exc

    return resolve


def prepare(cls: Any) -> None:
    """Resolve ``cls``'s nested types and make its leased class now (subscribe time), so that the first
    message pays for none of it (measured: a few milliseconds of imports and class creation)."""
    leased_class(cls)
    view_decoder(cls)
    resolve = _resolver(cls)
    todo, seen = [cls], set()
    while todo:
        current = todo.pop()
        for type_text in current._field_types:
            base = _split(type_text)[0]
            if base not in _SIZES and base not in seen:
                seen.add(base)
                try:
                    todo.append(resolve(base))
                except _NotViewable:
                    return


def field_offset(cls: Any, body: bytes, name: str) -> int:
    """Where the top-level field ``name`` starts in ``body`` (a message of ``cls``).

    Raises:
        LocalProtocolError: the type has no such field, or its layout cannot be walked here.
    """
    try:
        _walk(cls, memoryview(body), 0, resolve=_resolver(cls), stop=name)
    except _Found as found:
        return found.at
    except (_NotViewable, struct.error, AttributeError, ValueError) as exc:
        raise LocalProtocolError(f"cannot lay out a {cls._type} in place: {exc}") from None
    raise LocalProtocolError(f"{cls._type} has no field {name!r}")


_leased: dict[type, type] = {}


def leased_class(cls: Any) -> Any:
    """``cls`` with a lease: ``release()``, ``with msg:``, and the lease it holds (made once per type)."""
    got = _leased.get(cls)
    if got is None:

        class Leased(cls, gc=False):  # type: ignore[misc, valid-type, call-arg]
            _shm_lease: Any = None

            def release(self) -> None:
                """End the lease now: the publisher may reuse the slot; this message's views are released."""
                lease = self._shm_lease
                if lease is not None:
                    lease.release()

            def __enter__(self) -> Any:
                return self

            def __exit__(self, *exc_info: object) -> None:
                self.release()

        Leased.__name__ = Leased.__qualname__ = f"Leased{cls.__name__}"
        _leased[cls] = got = Leased
    return got


def decode_view(cls: Any, body: memoryview, lease: Any) -> tuple[Any, list[memoryview]]:
    """A message of ``leased_class(cls)`` decoded from ``body`` (read-only, in a leased slot), its large
    arrays views of ``body``; and those views (the lease releases them). No views: the message refers to
    nothing in the slot, and the caller may end the lease at once.

    Raises:
        DeserializationError: the body is not a message of ``cls`` (as ``deserialize`` would).
    """
    views: list[memoryview] = []
    leased = view_decoder(cls)(body, leased_class(cls), views)
    if views:
        leased._shm_lease = lease
    return leased, views
