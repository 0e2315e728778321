"""The daemon's two lists from the IXM paper, as plain data: processes and shared-memory segments.

The process list holds each connected client (name, pid, uid, keys held and in which mode); the segment
list holds each key (segment name, type, count or max size, creator, readers, writers). Methods check the
access rules and return the effects the server must perform (create a segment, unlink one, tell writers
that the readers to wake changed); nothing here touches a socket or shared memory, so that the rules of
IxmInit/IxmFree and of a process's death are tested without either.
"""

from __future__ import annotations

from collections.abc import Callable

import msgspec

from mrosd.errors import IxmError, IxmPermissionError
from mrosd.ixm.rules import AccessRules, Peer
from mrosd.ixm.types import IxmType, resolve_type

__all__ = [
    "CreateSegment",
    "ProcessInfo",
    "ReadersChanged",
    "Registry",
    "SegmentInfo",
    "UnlinkSegment",
]

Mode = str  # "r", "w" or "rw"
MODES = ("r", "w", "rw")

#: Keys one process may hold at once: bounds what one client can make the daemon allocate.
MAX_KEYS_PER_PROCESS = 1024
#: Longest key accepted (a key is a ROS-like name such as "/arm/joints").
MAX_KEY_LENGTH = 256


class ProcessInfo(msgspec.Struct, kw_only=True):
    """One connected client: the paper's process information list entry."""

    conn: int
    name: str
    peer: Peer
    keys: dict[str, Mode] = msgspec.field(default_factory=dict)


class SegmentInfo(msgspec.Struct, kw_only=True):
    """One key: the paper's shared-memory information list entry."""

    key: str
    shm_name: str
    type: IxmType
    creator_uid: int
    readers: set[int] = msgspec.field(default_factory=set)
    writers: set[int] = msgspec.field(default_factory=set)


class CreateSegment(msgspec.Struct, frozen=True):
    """Effect: allocate and initialise the segment before answering the open."""

    segment: SegmentInfo


class UnlinkSegment(msgspec.Struct, frozen=True):
    """Effect: the last holder released the key; unlink its segment."""

    key: str
    shm_name: str


class ReadersChanged(msgspec.Struct, frozen=True):
    """Effect: the set of readers of ``key`` changed; writers need the new wake-up list."""

    key: str


Effect = CreateSegment | UnlinkSegment | ReadersChanged


def check_key(key: object) -> str:
    """A key is a non-empty printable string of at most MAX_KEY_LENGTH characters."""
    if not isinstance(key, str) or not key or len(key) > MAX_KEY_LENGTH or not key.isprintable():
        raise IxmError(f"a key is a printable name of 1..{MAX_KEY_LENGTH} characters like '/arm/joints', got {key!r}")
    return key


class Registry:
    """Processes, segments and the access rules; every mutation returns the effects to perform."""

    def __init__(
        self,
        rules: AccessRules,
        name_segment: Callable[[str], str],
        max_keys: int | None = None,
        max_keys_per_uid: int | None = None,
    ) -> None:
        self.rules = rules
        self.processes: dict[int, ProcessInfo] = {}
        self.segments: dict[str, SegmentInfo] = {}
        self._name_segment = name_segment
        #: keys held (one per process and key) overall and per uid: each may cost the daemon a descriptor
        self.max_keys = max_keys
        self.max_keys_per_uid = max_keys_per_uid
        self.keys_held = 0
        self.keys_by_uid: dict[int, int] = {}

    def visible(self, peer: Peer, segment: SegmentInfo) -> bool:
        """Whether ``peer`` may open ``segment`` in some mode (what a listing shows it)."""
        return any(self.rules.allows(segment.key, peer, write, segment.creator_uid) for write in (False, True))

    def connect(self, conn: int, peer: Peer, name: str = "") -> ProcessInfo:
        info = ProcessInfo(conn=conn, name=name or next(iter(sorted(peer.names)), f"pid{peer.pid}"), peer=peer)
        self.processes[conn] = info
        return info

    def rename(self, conn: int, name: str) -> None:
        if name and name.isprintable() and len(name) <= MAX_KEY_LENGTH:
            self.processes[conn].name = name

    def open(  # noqa: PLR0917  (the paper's IxmInit arguments, in its order)
        self, conn: int, key: str, type_name: str | None, count: int | None, max_size: int | None, mode: Mode
    ) -> tuple[SegmentInfo, list[Effect]]:
        """IxmInit: grant ``mode`` on ``key`` to a connected process, creating the segment if needed.

        ``type_name`` None (or count/max_size None) means "whatever the existing key holds".

        Raises:
            IxmPermissionError: the rules refuse this process the mode.
            IxmError: bad key or mode, the key is already open in this process, or it exists with another type.
        """
        check_key(key)
        if mode not in MODES:
            raise IxmError(f"mode must be 'r', 'w' or 'rw', got {mode!r}")
        proc = self.processes[conn]
        if key in proc.keys:
            raise IxmError(f"{key} is already open in this process (mode {proc.keys[key]!r}); close it first")
        if len(proc.keys) >= MAX_KEYS_PER_PROCESS:
            raise IxmError(f"a process may hold at most {MAX_KEYS_PER_PROCESS} keys (limit reached); close some")
        uid = proc.peer.uid
        held = self.keys_by_uid.get(uid, 0)
        if self.max_keys_per_uid is not None and held >= self.max_keys_per_uid:
            raise IxmError(
                f"uid {uid} already holds {held} IXM keys, the per-user limit (max_keys_per_uid); close some"
            )
        if self.max_keys is not None and self.keys_held >= self.max_keys:
            raise IxmError(f"the IXM daemon holds {self.keys_held} keys, its limit (max_keys); try again later")
        seg = self.segments.get(key)
        creator = seg.creator_uid if seg is not None else None
        for write in (False, True):
            needed = "w" in mode if write else "r" in mode
            if needed and not self.rules.allows(key, proc.peer, write, creator):
                what = "write" if write else "read"
                raise IxmPermissionError(
                    f"uid {proc.peer.uid} (pid {proc.peer.pid}) may not {what} {key}: "
                    "the daemon's [ixm.rules] do not grant it"
                )
        effects: list[Effect] = []
        if seg is None:
            if type_name is None:
                raise IxmError(f"{key} does not exist yet; give its type to create it")
            wanted = resolve_type(type_name, count, max_size)
            seg = SegmentInfo(key=key, shm_name=self._name_segment(key), type=wanted, creator_uid=proc.peer.uid)
            effects.append(CreateSegment(seg))
        else:
            _check_compatible(key, seg.type, type_name, count, max_size)
        if "r" in mode:
            seg.readers.add(conn)
            effects.append(ReadersChanged(key))
        if "w" in mode:
            seg.writers.add(conn)
        proc.keys[key] = mode
        self.keys_held += 1
        self.keys_by_uid[uid] = held + 1
        if effects and isinstance(effects[0], CreateSegment):
            self.segments[key] = seg
        return seg, effects

    def close(self, conn: int, key: str) -> list[Effect]:
        """IxmFree: release one key; the last release unlinks the segment.

        Raises:
            IxmError: this process does not hold the key.
        """
        proc = self.processes[conn]
        if key not in proc.keys:
            raise IxmError(f"{key} is not open in this process")
        mode = proc.keys.pop(key)
        self.keys_held -= 1
        left = self.keys_by_uid[proc.peer.uid] - 1
        if left:
            self.keys_by_uid[proc.peer.uid] = left
        else:
            del self.keys_by_uid[proc.peer.uid]
        seg = self.segments[key]
        effects: list[Effect] = []
        seg.writers.discard(conn)
        if "r" in mode:
            seg.readers.discard(conn)
        if not seg.readers and not seg.writers:
            del self.segments[key]
            effects.append(UnlinkSegment(key, seg.shm_name))
        elif "r" in mode:
            effects.append(ReadersChanged(key))
        return effects

    def disconnect(self, conn: int) -> list[Effect]:
        """A client's socket closed (it exited or died): release everything it held."""
        proc = self.processes.get(conn)
        if proc is None:
            return []
        effects: list[Effect] = []
        for key in list(proc.keys):
            effects.extend(self.close(conn, key))
        del self.processes[conn]
        return effects


def _check_compatible(key: str, have: IxmType, type_name: str | None, count: int | None, max_size: int | None) -> None:
    if type_name is None:
        return
    name = type_name
    if "/" in name and name != have.name:
        name = resolve_type(name, None, have.max_size or None).name
    ok = name == have.name and (count is None or count == have.count)
    # a bounded value may be opened with a smaller (or the same) bound than the segment's
    ok = ok and (max_size is None or max_size <= have.capacity)
    if not ok:
        asked = type_name + (f"[{count}]" if count else "") + (f" max_size={max_size}" if max_size else "")
        raise IxmError(f"{key} holds {have.describe()} ({have.capacity} bytes); asked for {asked}")
