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
"""

from __future__ import annotations

from typing import Any

from mrosd.msg.loader import view_decoder

__all__ = ["decode_view", "leased_class", "prepare"]


def prepare(cls: Any) -> None:
    """Make ``cls``'s leased class and view decoder now (subscribe time, and a loaning publisher's
    advertise), so that the first message pays for neither (measured: a few milliseconds of code
    generation and class creation)."""
    leased_class(cls)
    view_decoder(cls)


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
