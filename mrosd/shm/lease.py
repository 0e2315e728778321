"""A zero-copy message in a subscriber's view of a shared-memory ring, and the lease that keeps its slot.

Owns ``ShmView``: what the application holds (the message's bytes and a typed message's arrays as
read-only views of the slot) and when its lease ends (``release()``, ``with``, or once nothing references
its views any more, whatever thread drops it). Must not know how the ring is read or acknowledged: the
connection that leased it (``mrosd.shm.subscriber``) is seen only as a ``LeaseHolder``.
"""

from __future__ import annotations

import contextlib
import sys
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from mrosd.shm.ring import RingLayout

__all__ = ["LeaseHolder", "ShmView"]


class LeaseHolder(Protocol):
    """The connection that leased a view: told when its lease ends, or that a view of it lives on."""

    def end_lease(self, index: int) -> None: ...

    def keep_lease(self, view: ShmView) -> None: ...


def _refs(views: list[memoryview]) -> int:
    """The most references any of ``views`` has (the list's, the loop's, getrefcount's argument: unused)."""
    return max((sys.getrefcount(view) for view in views), default=0)


#: what ``_refs`` says of views nothing else references (measured, not assumed)
_UNUSED = _refs([memoryview(b"")])


class ShmView:
    """A zero-copy, read-only view of one message in a slot of the publisher's ring, under a lease.

    The subscriber wrote the message's number into one of its lease words before it took the view: the
    publisher does not write that slot until the lease ends, whether this subscriber keeps up or lags. The
    lease ends with ``release()`` (or ``with view:``), or once neither the view nor anything made from it is
    referenced any more (``data``, a typed message's arrays in ``views``, a numpy array over them): not when a
    callback returns, so a view may go to another thread. ``release()`` releases ``data`` and ``views`` too,
    so that a use after it raises ``ValueError`` rather than read a slot that may hold another message by
    then. ``intact()``: the slot still holds this message (always True under a lease).
    """

    __slots__ = ("__weakref__", "_conn", "_layout", "_slot", "index", "number", "views")

    def __init__(
        self, conn: LeaseHolder, layout: RingLayout | None, data: memoryview, *, number: int, slot: int, index: int
    ) -> None:
        self._conn: LeaseHolder | None = conn
        self._layout = layout
        self._slot = slot
        self.index = index
        self.number = number
        #: every view of the slot handed out: the message's bytes first, then a typed message's arrays
        self.views: list[memoryview] = [data]

    @property
    def data(self) -> memoryview:
        """The message's serialized bytes, read-only, in the slot."""
        return self.views[0]

    def intact(self) -> bool:
        layout = self._layout
        try:
            return layout is not None and bool(layout.words[self._slot][0] == 2 * self.number)
        except ValueError:  # the ring was unmapped (the connection ended)
            return False

    @property
    def leased(self) -> bool:
        return self._conn is not None

    def in_use(self) -> bool:
        """Is any of its views referenced or exported outside this object?"""
        return _refs(self.views) > _UNUSED

    def release_views(self) -> None:
        for view in self.views:
            with contextlib.suppress(BufferError):  # exported (numpy): it stays readable; the slot may change
                view.release()

    def release(self) -> None:
        """End the lease now (idempotent); its views are released (a use after it is a ``ValueError``)."""
        conn, self._conn = self._conn, None
        if conn is not None:
            self.release_views()
            conn.end_lease(self.index)

    def __del__(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            if self.in_use():
                conn.keep_lease(self)  # a view of it lives on: the lease lasts until that is gone
            else:
                self.release_views()
                conn.end_lease(self.index)

    def __enter__(self) -> ShmView:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()
