"""Which connections the master keeps: caps by who is calling, not by address (pure; no sockets).

A remote peer is its address. A local peer (a loopback address, or the host's own) is the uid owning its
socket: every node of the robot connects from 127.0.0.1, so a cap per address let one flooding uid lock out
all the others. The uid costs a kernel lookup, so it is asked for only when it matters: once local peers
(whatever loopback address each uses) hold ``per_who`` connections in all, or all ``total`` slots are taken
(``needs_identity``); below that no uid can be over its share. Connections admitted before then are
identified in one pass when it first matters (the caller looks up each of ``unidentified()`` once).

Refusal and shedding (``admit``):

* a who already holding ``per_who`` connections is refused;
* when all ``total`` slots are taken, the who holding the most connections gives up its oldest connection
  that is not running a call (``sheddable``) to a newcomer of another who; if it has none, or the newcomer is
  that who, the newcomer is refused.

``C`` is the caller's connection object (hashable, with a ``sheddable`` property read at decision time).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar


class Connection(Protocol):
    """What the policy reads of a connection."""

    @property
    def sheddable(self) -> bool:
        """Nothing running for it: closing it loses no answer (idle, or a request still arriving)."""
        ...


C = TypeVar("C", bound=Connection)

#: ``("uid", 1000)`` for a local peer told apart by uid, ``("addr", "10.0.0.5")`` otherwise.
Who = tuple[str, int | str]


def describe(who: Who) -> str:
    """``uid 1000`` or the address, for log lines and refusal reasons."""
    kind, value = who
    return f"uid {value}" if kind == "uid" else str(value)


@dataclass(frozen=True, slots=True)
class Decision(Generic[C]):
    """``admit``'s verdict: whether the newcomer is in, which connection to close for it (and whose), and why
    a newcomer is refused."""

    admitted: bool
    shed: C | None = None
    shed_from: str = ""
    reason: str = ""


class Admission(Generic[C]):
    """Connection accounting per who and per address; decides on each newcomer.

    Args:
        total: open connections in all.
        per_who: open connections of one remote address or one local uid.
    """

    def __init__(self, total: int, per_who: int) -> None:
        if total < 1 or per_who < 1:
            raise ValueError("connection caps must be at least 1")
        self.total = total
        self.per_who = per_who
        self._by_who: dict[Who, dict[C, None]] = {}  # insertion order: oldest first
        self._who: dict[C, Who] = {}
        self._local_unidentified: dict[C, None] = {}
        self._local: dict[C, None] = {}

    def __len__(self) -> int:
        return len(self._who)

    def count(self, who: Who) -> int:
        return len(self._by_who.get(who, ()))

    def needs_identity(self, local: bool) -> bool:
        """Whether a newcomer must be told apart by uid before deciding (and the unidentified others first)."""
        if len(self._who) >= self.total:
            return True
        return local and len(self._local) >= self.per_who

    def unidentified(self) -> list[C]:
        """Local connections admitted without a uid; look each up once and ``identify`` it."""
        return list(self._local_unidentified)

    def identify(self, conn: C, uid: int | None) -> None:
        """Record the uid of a local connection (None: it cannot be told; it stays counted by address)."""
        if conn not in self._local_unidentified:
            return
        del self._local_unidentified[conn]
        if uid is not None:
            self._move(conn, ("uid", uid))

    def admit(self, conn: C, host: str, local: bool, uid: int | None) -> Decision[C]:
        """Decide on a newcomer; when admitted it is counted (and ``shed``, if any, already forgotten)."""
        who: Who = ("uid", uid) if local and uid is not None else ("addr", host)
        if self.count(who) >= self.per_who:
            return Decision(False, reason=f"connection cap reached for {describe(who)}")
        shed: C | None = None
        shed_from = ""
        if len(self._who) >= self.total:
            shed = self._victim(who)
            if shed is None:
                return Decision(False, reason="connection cap reached for all clients")
            shed_from = describe(self._who[shed])
            self.forget(shed)
        self._who[conn] = who
        self._by_who.setdefault(who, {})[conn] = None
        if local:
            self._local[conn] = None
            if uid is None:
                self._local_unidentified[conn] = None
        return Decision(True, shed, shed_from)

    def forget(self, conn: C) -> None:
        """A connection is gone (closed by either side, or shed): its slot is free."""
        who = self._who.pop(conn, None)
        if who is None:
            return
        self._local_unidentified.pop(conn, None)
        self._local.pop(conn, None)
        group = self._by_who[who]
        del group[conn]
        if not group:
            del self._by_who[who]

    def _move(self, conn: C, who: Who) -> None:
        old = self._who[conn]
        group = self._by_who[old]
        del group[conn]
        if not group:
            del self._by_who[old]
        self._who[conn] = who
        self._by_who.setdefault(who, {})[conn] = None

    def _victim(self, newcomer: Who) -> C | None:
        """The oldest sheddable connection of the who holding the most, unless that is the newcomer's own."""
        if not self._by_who:
            return None
        biggest = max(self._by_who, key=lambda w: len(self._by_who[w]))
        if biggest == newcomer or len(self._by_who[biggest]) <= self.count(newcomer) + 1:
            return None
        for conn in self._by_who[biggest]:
            if conn.sheddable:
                return conn
        return None
