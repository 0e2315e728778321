"""Loaned messages: a message whose array is filled in place in a slot of the shared-memory pool.

``make_loan(publisher, template, sizes)`` takes a slot out of the publisher's ring
(``ShmPublisherEndpoint.loan_slot``) and returns a message of the topic's type whose one ``uint8[]``/
``char[]`` field is a writable memoryview of that slot, at ``LOAN_HEAD``; the application fills it
(``np.frombuffer(msg.data, np.uint8)`` is a writable array over it) and sets the other fields as usual.
``publish_loan`` then serializes only the small rest of the message (the field cut out), writes the part
before the array in front of it and the part after it behind it, and publishes the slot as it is: no byte
of the array is copied. The same bytes go to the topic's TCPROS subscribers as a view of the slot (the
slot stays out of the ring while a socket still holds some of them to send). Without a declared pool, or
when the ring cannot lend a slot (messages waiting, every slot busy), the array is a plain ``bytearray``
and publishing copies it as always: the same API either way.

A loan is published once: publishing it again, or reading or writing its array after publishing, is a
``LocalProtocolError`` / ``ValueError`` (the view is released; a numpy array made from it must not be used
after publishing: it is not ours to revoke).
"""

from __future__ import annotations

import contextlib
from typing import Any

from mrosd.errors import LocalProtocolError
from mrosd.shm.publisher import LOAN_HEAD, LOAN_TAIL, ShmPublisherEndpoint
from mrosd.shm.segment import RingSegment
from mrosd.wire.framing import frame_prefix

__all__ = ["Loan", "loaned_class", "make_loan", "publish_loan"]

_BYTE_ARRAYS = ("uint8[]", "char[]")


class Loan:
    """One lent slot (or a private buffer, ``ring`` None) and the state of its message."""

    __slots__ = ("endpoint", "field", "published", "ring", "size", "slot", "view")

    def __init__(
        self,
        field: str,
        size: int,
        view: memoryview,
        *,
        endpoint: ShmPublisherEndpoint | None = None,
        ring: RingSegment | None = None,
        slot: int = -1,
    ) -> None:
        self.field = field
        self.size = size
        self.view = view
        self.endpoint = endpoint
        self.ring = ring
        self.slot = slot
        self.published = False

    @property
    def in_place(self) -> bool:
        """The array is in a pool slot (False: a private buffer, copied when published)."""
        return self.ring is not None

    def close(self) -> None:
        """Give the slot back unpublished (a loan dropped without publishing)."""
        if not self.published and self.endpoint is not None and self.ring is not None:
            self.endpoint.end_loan(self.ring, self.slot)
        self.published = True


_loaned: dict[type, type] = {}


def loaned_class(cls: Any) -> Any:
    """``cls`` with a loan attached (made once per type); publishes like ``cls``."""
    got = _loaned.get(cls)
    if got is None:

        class Loaned(cls, gc=False):  # type: ignore[misc, valid-type, call-arg]
            _shm_loan: Any = None

            def __del__(self) -> None:
                loan = self._shm_loan
                if loan is not None:
                    loan.close()

        Loaned.__name__ = Loaned.__qualname__ = f"Loaned{cls.__name__}"
        _loaned[cls] = got = Loaned
    return got


def make_loan(publisher: Any, template: Any, sizes: dict[str, int]) -> Any:
    """A message of ``publisher.msg_class`` whose array field is a writable view into a pool slot.

    ``sizes``: one ``field=bytes`` (``loan(data=640 * 480 * 3)``); or ``template``: a message whose other
    fields are copied and whose largest ``uint8[]`` field gives the size (its contents are not copied).

    Raises:
        LocalProtocolError: not exactly one byte-array field, or the field is not a top-level ``uint8[]``.
    """
    cls = publisher.msg_class
    types = dict(zip(cls.__struct_fields__, cls._field_types, strict=False))
    fields: dict[str, Any] = {}
    if template is not None:
        arrays = [f for f, t in types.items() if t in _BYTE_ARRAYS]
        if not arrays or sizes:
            raise LocalProtocolError("loan(template) needs a message with a uint8[] field, and no sizes")
        name = max(arrays, key=lambda f: len(getattr(template, f)))
        size = len(getattr(template, name))
        fields = {f: getattr(template, f) for f in cls.__struct_fields__ if f != name}
    else:
        if len(sizes) != 1:
            raise LocalProtocolError("loan one array field by its size in bytes, e.g. loan(data=640 * 480 * 3)")
        ((name, size),) = sizes.items()
    if types.get(name) not in _BYTE_ARRAYS:
        raise LocalProtocolError(f"{cls._type}.{name} is not a uint8[]/char[] field: it cannot be loaned")
    if size < 0:
        raise LocalProtocolError(f"a loan of {size} bytes")
    side = getattr(publisher, "shm", None)
    endpoint: ShmPublisherEndpoint | None = side.endpoint if side is not None else None
    got = endpoint.loan_slot(size) if endpoint is not None else None
    if got is not None:
        ring, slot = got
        view = ring.layout.data[slot][LOAN_HEAD : LOAN_HEAD + size]
        loan = Loan(name, size, view, endpoint=endpoint, ring=ring, slot=slot)
    else:
        loan = Loan(name, size, memoryview(bytearray(size)))
    msg = loaned_class(cls)(**fields, **{name: loan.view})
    msg._shm_loan = loan
    return msg


def _around(publisher: Any, msg: Any, loan: Loan) -> tuple[bytes, bytes]:
    """The serialized message before the loaned array (ending with its length) and after it.

    ``serialize_parts`` hands the array back as a piece of its own (the very view lent), with the rest
    packed around it: no walk of the type's fields is needed to place it (that walk, in Python, was a
    quarter of the publish call's time after an idle period).
    """
    parts = msg.serialize_parts()
    for i, part in enumerate(parts):
        if part is loan.view:
            return b"".join(parts[:i]), b"".join(parts[i + 1 :])
    raise LocalProtocolError(f"the loaned field {loan.field!r} is not serialized from the loaned view")


def publish_loan(publisher: Any, msg: Any) -> None:
    """Publish a loaned message (``Publisher.publish`` calls this; ``header.seq`` is already set).

    Raises:
        LocalProtocolError: it was published already, or its array field was replaced by another object.
    """
    loan: Loan = msg._shm_loan
    if loan.published:
        raise LocalProtocolError(f"this loaned {publisher.type} was published already: loan another one")
    name = loan.field
    if getattr(msg, name) is not loan.view:
        raise LocalProtocolError(f"the loaned field {name!r} was replaced: fill the loaned view instead")
    head, tail = _around(publisher, msg, loan)
    endpoint, ring = loan.endpoint, loan.ring
    if (
        endpoint is not None
        and ring is not None
        and ring is endpoint.ring
        and len(head) <= LOAN_HEAD
        and len(tail) <= LOAN_TAIL
    ):
        data = ring.layout.data[loan.slot]
        start = LOAN_HEAD - len(head)
        data[start:LOAN_HEAD] = head
        data[LOAN_HEAD + loan.size : LOAN_HEAD + loan.size + len(tail)] = tail
        length = len(head) + loan.size + len(tail)
        body = data[start : start + length].toreadonly()
        in_place = endpoint.publish_loaned(ring, loan.slot, start, length)
        if not in_place:
            endpoint.publish_parts((body,), length)  # the ring moved on, or messages wait: one copy
        _send_tcpros(publisher, body, endpoint if in_place else None, loan.slot)
    else:
        if endpoint is not None and ring is not None:
            endpoint.end_loan(ring, loan.slot)
        body = memoryview(b"".join((head, loan.view, tail)))  # no pool: one copy, as serialize() makes
        if publisher.shm is not None:
            publisher.shm.publish(body)
        _send_tcpros(publisher, body, None, -1)
    loan.published = True
    with contextlib.suppress(BufferError):  # an array made from it is the caller's to stop using
        loan.view.release()


def _send_tcpros(publisher: Any, body: memoryview, endpoint: ShmPublisherEndpoint | None, slot: int) -> None:
    """Send ``body`` to the TCPROS subscribers: as a view of the slot where a socket takes it now, the slot
    then kept unwritten while any socket still holds part of it; a copy to a subscriber with a queue."""
    publisher.messages_published += 1
    size = len(body)
    prefix = frame_prefix(size)
    if publisher.latch:
        publisher.latched = prefix + bytes(body)
    transports = []
    copy: bytes | None = None
    for link in publisher.links:
        proto = link.proto
        if endpoint is not None and not link.queue and not proto.paused and proto.transport is not None:
            link.send_parts((prefix, body), size + 4)
            transports.append(proto.transport)
        else:
            if copy is None:
                copy = bytes(body)
            link.send_parts((prefix, copy), size + 4)
    if endpoint is not None and transports:
        pending = [t for t in transports if t.get_write_buffer_size() > 0]
        if pending:
            endpoint.pin(slot, lambda: any(t.get_write_buffer_size() > 0 and not t.is_closing() for t in pending))
