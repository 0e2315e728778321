"""What the IXM daemon holds for its clients: sealed memfd segments, writers' notice pages, and the caps.

A segment is a memfd sized once, its header written with ``pwrite`` (the daemon never maps a segment),
made mode 0600 (so that another uid cannot reopen a read-only descriptor read-write through /proc), then
sealed against shrinking, growing and any further seal before a client sees it: no client can resize it
(no SIGBUS for the daemon or other readers) or freeze it for other writers, and it has no name in
/dev/shm for anyone to squat. Each client gets its own open file description (reopened through
/proc/self/fd), read-only for readers. Writers serialise with ``flock`` on a second, empty memfd that
only writers receive: a reader can take a lock on its own descriptor, but never on the writers' one, so it
cannot stall them.
"""

from __future__ import annotations

import contextlib
import fcntl
import mmap
import os
from collections.abc import Iterable

import msgspec

from mrosd.ixm.channel import MAX_FDS_PER_MESSAGE
from mrosd.ixm.layout import SegmentLayout
from mrosd.ixm.registry import SegmentInfo

__all__ = [
    "MAX_WAKE_READERS",
    "WAKE_SHARES",
    "WAKE_SLOTS_PER_UID",
    "Limits",
    "NoticePage",
    "Segment",
    "held_memfds",
    "reopen",
    "sealed_memfd",
    "wake_slot_refusal",
]

#: A key's woken-reader slots: the readers' wake-up pipes one writer can be handed in one sendmsg (the
#: kernel's SCM_MAX_FD).
MAX_WAKE_READERS = MAX_FDS_PER_MESSAGE
#: A uid may hold at most 1/WAKE_SHARES of a key's woken-reader slots (63 of 253): one uid then leaves at
#: least 190 to the others, and a key is full only once five uids hold their share, which a user without
#: root cannot make up on its own.
WAKE_SHARES = 4
WAKE_SLOTS_PER_UID = MAX_WAKE_READERS // WAKE_SHARES


def wake_slot_refusal(key: str, holders: Iterable[int], uid: int) -> str:
    """Why a new woken reader of ``key`` by ``uid`` is refused, given the uids of the woken readers it
    already has (one entry per reader), or "" when it may have a slot."""
    total = mine = 0
    for holder in holders:
        total += 1
        mine += holder == uid
    if total >= MAX_WAKE_READERS:
        return f"{key} already has {MAX_WAKE_READERS} woken readers, the most one writer can signal"
    if mine >= WAKE_SLOTS_PER_UID:
        return (
            f"uid {uid} already has {mine} woken readers of {key}, its share "
            f"({WAKE_SLOTS_PER_UID} of {MAX_WAKE_READERS}); close some"
        )
    return ""


_SEALS = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL


class Limits(msgspec.Struct, frozen=True, kw_only=True):
    """Caps on what clients can make the daemon hold (each connection and each key held costs descriptors)."""

    max_clients: int
    max_clients_per_uid: int
    max_keys: int
    max_keys_per_uid: int

    @classmethod
    def for_fd_limit(cls, soft_limit: int, **given: int | None) -> Limits:
        """Defaults that keep IXM within 3/4 of ``soft_limit`` (a connection costs one descriptor, a key held
        up to three: a reader's wake-up pipe and, for its creator, the segment and the writers' lock), leaving the
        rest to the master; values in ``given`` (not None) are taken as they are."""
        budget = max(64, soft_limit * 3 // 4)
        clients = min(4096, budget // 4)
        keys = min(65536, (budget - clients) // 3)
        defaults = {
            "max_clients": clients,
            "max_clients_per_uid": min(1024, max(4, clients // 4)),
            "max_keys": keys,
            "max_keys_per_uid": min(16384, max(8, keys // 4)),
        }
        return cls(**{k: v if given.get(k) is None else int(given[k] or 0) for k, v in defaults.items()})


def sealed_memfd(name: str, size: int, head: bytes = b"") -> int:
    """A memfd of ``size`` bytes starting with ``head``, mode 0600, sealed against resizing and new seals."""
    fd = os.memfd_create(name, os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    try:
        os.ftruncate(fd, size)
        if head:
            os.pwrite(fd, head, 0)
        os.fchmod(fd, 0o600)
        fcntl.fcntl(fd, fcntl.F_ADD_SEALS, _SEALS)
    except BaseException:
        os.close(fd)
        raise
    return fd


def reopen(fd: int, write: bool) -> int:
    """A new open file description of ``fd``'s file (own flock state), read-only unless ``write``."""
    return os.open(f"/proc/self/fd/{fd}", (os.O_RDWR if write else os.O_RDONLY) | os.O_CLOEXEC)


class Segment:
    """One key's memfd (the daemon's descriptor, never mapped here) and its readers' wake-up pipes (write ends)."""

    def __init__(self, info: SegmentInfo) -> None:
        t = info.type
        head = SegmentLayout.header(t.code, t.capacity, t.count, t.name)
        self.fd = sealed_memfd(info.shm_name.removeprefix("memfd:"), SegmentLayout.segment_size(t.capacity), head)
        self.info = info
        #: the writers' lock file, created at the first open for writing
        self.lock_fd: int | None = None
        #: reader connection -> the daemon's copy of its wake-up pipe's write end
        self.wake_fds: dict[int, int] = {}

    def fds_to_wake(self, writer: int) -> list[int]:
        """The readers' wake-up pipes the writer connection ``writer`` signals (its own excluded), in a stable order."""
        return [fd for conn, fd in sorted(self.wake_fds.items()) if conn != writer]

    def open_fd(self, write: bool) -> int:
        return reopen(self.fd, write)

    def open_lock(self) -> int:
        """A writer's own descriptor of the writers' lock file (its own open file description)."""
        if self.lock_fd is None:
            self.lock_fd = sealed_memfd("mrosd-lock-" + self.info.shm_name.removeprefix("memfd:"), 0)
        return reopen(self.lock_fd, write=False)

    def close(self) -> None:
        for fd in self.wake_fds.values():
            with contextlib.suppress(OSError):
                os.close(fd)
        self.wake_fds.clear()
        for held in (self.fd, self.lock_fd):
            if held is not None:
                with contextlib.suppress(OSError):
                    os.close(held)


class NoticePage:
    """A writer connection's page: the count of WakeList pushes sent to it, which it maps read-only."""

    def __init__(self, name: str) -> None:
        fd = sealed_memfd(name, mmap.PAGESIZE)
        try:
            self.map = mmap.mmap(fd, mmap.PAGESIZE)
            self.client_fd = reopen(fd, write=False)
        finally:
            os.close(fd)
        self.count = memoryview(self.map)[:8].cast("Q")

    def close(self) -> None:
        self.count.release()
        self.map.close()


def held_memfds(prefix: str) -> set[str]:
    """Names of the memfds starting with ``prefix`` that some process on the machine holds open.

    Segments have no name in /dev/shm, so this is how leak checks (tests, the soak) see them: through
    ``/proc/<pid>/fd`` links (``/memfd:<name> (deleted)``); processes we may not inspect are skipped.
    """
    names: set[str] = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if link.startswith("/memfd:" + prefix):
                names.add(link.removeprefix("/memfd:").removesuffix(" (deleted)"))
    return names
