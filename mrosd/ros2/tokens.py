"""Liveliness tokens from Zenoh's threads to the loop, so that no session's flood pushes out or holds up another's.

rmw_zenoh's graph is liveliness tokens, and any peer can declare any number of them (a bare Zenoh session
forges rmw_zenoh's keys in microseconds each). The bridge needs only a few kinds: publishers and servers on
names ``from_ros2`` imports, and, in mode "demand", subscribers of names it sends. ``TokenFilter`` says on
Zenoh's thread, from the key's chunks alone, whether a token can matter; the rest are dropped there and cost
the loop nothing. ``TokenLanes`` holds the ones that can matter in one FIFO per session id the key names (a
token's appearing and going stay in order) and hands them out in turn, one lane after the other, so a session
that declares ten thousand waits behind itself, not in front of an honest publisher. A session id in a key
is a claim: a flood spread over forged ids gets a turn per id, which is why the filter comes first and why
the lanes hold ``MAX_WAITING`` tokens in all, dropping the oldest of the longest lane (never a lane's only
token while a longer one exists). No I/O here: the bridge wakes its loop.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import TYPE_CHECKING

from mrosd.ros2.keys import MAX_TOKEN_LENGTH, demangle_name

if TYPE_CHECKING:
    from mrosd.fleet.keys import NameFilter

__all__ = ["MAX_LANES", "MAX_WAITING", "TokenFilter", "TokenLanes"]

#: tokens waiting for the loop over all lanes (each at most ``MAX_TOKEN_LENGTH`` characters: 16 MiB at worst)
MAX_WAITING = 4096
#: lanes at once; tokens of further session ids share one overflow lane
MAX_LANES = 256
#: the lane of tokens that cannot be parsed or whose session id is past ``MAX_LANES``
OVERFLOW = ""

#: one waiting token: its key (None: too long to be rmw_zenoh's) and whether it appeared (else it went)
Token = tuple[str | None, bool]


class TokenFilter:
    """Whether a token's key can matter to the bridge, from its chunks (no full parse; ``parse_token`` decides
    later): publishers (``MP``) and servers (``SS``) of imported names; subscribers (``MS``) of sent names in
    mode "demand"; never our own session's, never another domain's, never a node's or a client's."""

    def __init__(self, domain_id: int, own_zid: str, imported: NameFilter, sent: NameFilter | None) -> None:
        self.domain = str(domain_id)
        self.own_zid = own_zid
        self.imported = imported
        #: mode "demand": the names whose ROS 2 subscribers make them cross; None in the other modes
        self.sent = sent

    def session_of(self, key: str) -> str | None:
        """The session id the key names if the token can matter, else None."""
        if len(key) > MAX_TOKEN_LENGTH:
            return OVERFLOW  # the loop logs it (rate-limited) as too long
        parts = key.split("/", 10)
        if len(parts) < 11 or parts[1] != self.domain or parts[2] == self.own_zid:
            return None
        kind = parts[5]
        if kind in ("MP", "SS"):
            names = self.imported
        elif kind == "MS" and self.sent is not None:
            names = self.sent
        else:
            return None
        return parts[2] if demangle_name(parts[9]) in names else None


class TokenLanes:
    """Waiting tokens, one FIFO per session id, taken in turn (any thread puts, the loop takes)."""

    def __init__(self, max_waiting: int = MAX_WAITING, max_lanes: int = MAX_LANES) -> None:
        self.max_waiting = max_waiting
        self.max_lanes = max_lanes
        self._lock = threading.Lock()
        self._lanes: dict[str, deque[Token]] = {}
        #: session ids with tokens waiting, in the order they get their next turn
        self._turns: deque[str] = deque()
        self.waiting = 0
        self.dropped = 0

    def put(self, session: str, token: Token) -> tuple[bool, bool]:
        """Queue ``token`` in ``session``'s lane; returns (the lanes were empty, a token was dropped)."""
        with self._lock:
            was_empty = self.waiting == 0
            lane = self._lanes.get(session)
            if lane is None:
                if len(self._lanes) >= self.max_lanes:
                    session = OVERFLOW
                    lane = self._lanes.get(session)
                if lane is None:
                    lane = self._lanes[session] = deque()
                    self._turns.append(session)
            dropped = False
            if self.waiting >= self.max_waiting:
                longest = max(self._lanes, key=lambda s: len(self._lanes[s]))
                if len(self._lanes[longest]) <= len(lane):
                    longest = session  # never push out a shorter lane for a longer one's sake
                self._lanes[longest].popleft()
                self.waiting -= 1
                self.dropped += 1
                dropped = True
                if not self._lanes[longest] and longest != session:
                    del self._lanes[longest]
                    self._turns.remove(longest)
            lane.append(token)
            self.waiting += 1
            return was_empty, dropped

    def take(self, most: int) -> list[Token]:
        """Up to ``most`` tokens, one from each lane in turn (each lane's own order kept)."""
        out: list[Token] = []
        with self._lock:
            while self._turns and len(out) < most:
                session = self._turns.popleft()
                lane = self._lanes[session]
                out.append(lane.popleft())
                if lane:
                    self._turns.append(session)
                else:
                    del self._lanes[session]
            self.waiting -= len(out)
        return out
