"""The memfd that holds a ring: created, mapped and sealed by the publisher; checked and mapped by subscribers.

The publisher creates the memfd (mode 0600, no name in /dev/shm), sizes it, maps it read-write, writes the
ring header, and only then seals it: ``F_SEAL_SHRINK | F_SEAL_GROW`` (no one can resize it, so no reader
can be hit by SIGBUS), ``F_SEAL_FUTURE_WRITE`` (from now on no one, not even a process of the same uid
reopening a reader's descriptor read-write through /proc, can write to it or map it writable; the
publisher's own mapping, made before, stays writable) and ``F_SEAL_SEAL``. Each subscriber gets its own
read-only open file description (``mrosd.ixm.resources.reopen``) over its Unix socket. A subscriber checks
the seals before mapping what it received (a publisher that sends an unsealed file could shrink it under the
reader's feet) and maps it ``PROT_READ``. The kernel frees the memory with the last descriptor or mapping:
a process killed at any point leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import mmap
import os
import sys

from mrosd.errors import RemoteProtocolError
from mrosd.ixm.resources import reopen, sealed_memfd
from mrosd.shm.ring import POPULATED, RingLayout, ring_size

__all__ = [
    "ACK_PAGE",
    "F_SEAL_FUTURE_WRITE",
    "MAX_LEASES",
    "SEGMENT_PREFIX",
    "AckPage",
    "MappedAck",
    "MappedRing",
    "RingSegment",
]

log = logging.getLogger(__name__)

#: Linux 5.1's seal (not in Python's fcntl): no new writable mapping or write(), existing mappings keep working.
F_SEAL_FUTURE_WRITE = 0x0010
_REQUIRED = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW
_SEALS = _REQUIRED | F_SEAL_FUTURE_WRITE | fcntl.F_SEAL_SEAL
#: Rings show in /proc/PID/fd as ``/memfd:mrosd-shm-<topic> (deleted)``.
SEGMENT_PREFIX = "mrosd-shm-"
#: Size of a subscriber's acknowledgement page: word 0 is the next message it wants, words 1..``MAX_LEASES``
#: the messages it holds leases on (0: none), of which the publisher reads only as many as it granted.
ACK_PAGE = 4096
#: Leases a subscriber may be granted at most (its page has room for many more: the publisher reads no more).
MAX_LEASES = 16
#: madvise advice of Linux 5.14 (not in Python 3.11's mmap): fault every page of a range in, readable or writable.
MADV_POPULATE_READ = 22
MADV_POPULATE_WRITE = 23
_PAGE = mmap.PAGESIZE


def fault_in(mapping: mmap.mmap, *, write: bool) -> None:
    """Fault every page of ``mapping`` in now, so that no later access pays for it: one ``madvise`` call
    (Linux 5.14+), else one access per page (a write of the zero a fresh page already holds, or a read)."""
    try:
        mapping.madvise(MADV_POPULATE_WRITE if write else MADV_POPULATE_READ)
        return
    except (OSError, ValueError):
        pass
    view = memoryview(mapping)
    try:
        if write:
            for at in range(0, len(view), _PAGE):
                view[at] = view[at]
        else:
            bytes(view[::_PAGE])
    finally:
        view.release()


class RingSegment:
    """The publisher's ring: its memfd and read-write mapping.

    ``populate``: fault every page in now (a pool made once, up front, for a publisher that declared its
    message size: ~0.7 ms per MB here, paid at advertise time instead of by the first messages) and say so
    in the header, so that subscribers map it whole at once too.
    """

    def __init__(self, label: str, slots: int, capacity: int, head: int = 0, *, populate: bool = False) -> None:
        size = ring_size(slots, capacity)
        fd = os.memfd_create((SEGMENT_PREFIX + label)[:200], os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
        try:
            os.ftruncate(fd, size)
            os.fchmod(fd, 0o600)
            # Unless asked: fresh shared memory costs ~0.7 ms per MB here however it is touched (MAP_POPULATE,
            # MADV_POPULATE_WRITE or a first write all measured alike), so by default a slot gets its pages when
            # it is first written, and a ring whose messages are smaller than its slots never pays for the rest.
            self.map = mmap.mmap(fd, size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            try:
                if populate:
                    fault_in(self.map, write=True)
                flags = POPULATED if populate else 0
                self.layout = RingLayout.initialize(memoryview(self.map), slots, capacity, head, flags)
                fcntl.fcntl(fd, fcntl.F_ADD_SEALS, _SEALS)
            except BaseException:
                self.map.close()
                raise
        except BaseException:
            os.close(fd)
            raise
        self.fd = fd
        self.size = size

    def reader_fd(self) -> int:
        """A new read-only descriptor for one subscriber (the caller sends it, then closes it)."""
        return reopen(self.fd, write=False)

    def close(self) -> None:
        self.layout.release()
        with contextlib.suppress(BufferError):  # a loaned view is still out: the mapping goes with it
            self.map.close()
        with contextlib.suppress(OSError):
            os.close(self.fd)


class MappedRing:
    """A subscriber's read-only mapping of a ring it received; takes ownership of ``fd`` (closed here).

    Raises:
        RemoteProtocolError: the file is not a sealed memfd, is larger than ``max_bytes``, or is not a ring.
    """

    def __init__(self, fd: int, max_bytes: int) -> None:
        try:
            try:
                seals = fcntl.fcntl(fd, fcntl.F_GET_SEALS)
            except OSError:
                raise RemoteProtocolError("the publisher sent a file that is not a sealable memfd") from None
            if seals & _REQUIRED != _REQUIRED:
                raise RemoteProtocolError("the publisher sent a ring that is not sealed against resizing")
            size = os.fstat(fd).st_size
            if not 0 < size <= max_bytes:
                raise RemoteProtocolError(f"the publisher sent a ring of {size} bytes (at most {max_bytes} accepted)")
            try:
                # not populated: a read fault maps the publisher's pages 16 at a time (fault-around), and
                # populating would make this process allocate the slots the publisher has not written yet
                self.map = mmap.mmap(fd, size, mmap.MAP_SHARED, mmap.PROT_READ)
            except OSError as exc:
                raise RemoteProtocolError(f"cannot map the publisher's ring: {exc.strerror or exc}") from None
        finally:
            os.close(fd)
        try:
            self.layout = RingLayout(memoryview(self.map))
        except BaseException:
            self.map.close()
            raise
        if ring_size(self.layout.slots, self.layout.capacity) > size:
            self.close()
            raise RemoteProtocolError("the publisher's ring is smaller than its header says")
        if self.layout.flags & POPULATED:
            # The publisher's pages all exist: map them all now, once per ring, rather than 16 at a time on
            # the data path (a lying flag only makes us map what we were allowed to map anyway).
            with contextlib.suppress(OSError):
                fault_in(self.map, write=False)

    def close(self) -> None:
        self.layout.release()
        try:
            self.map.close()
        except BufferError:
            # a zero-copy view is still referenced: the mapping goes when that view does
            log.debug("a shared-memory view outlives its connection; the mapping is freed with it")


class AckPage:
    """The publisher's side of one subscriber's acknowledgement page: a sealed 4 KiB memfd whose first word
    the subscriber writes (the number of the next message it wants, ``first`` to begin with); the publisher
    only reads it.

    The publisher makes it and sends it writable to that subscriber alone; sealed against resizing, so no
    one can make the publisher's mapping fault. What the word says is trusted for nothing but that
    subscriber's own pace (``mrosd.shm.publisher`` clamps it).
    """

    def __init__(self, label: str, first: int) -> None:
        fd = sealed_memfd((SEGMENT_PREFIX + "ack-" + label)[:200], ACK_PAGE, first.to_bytes(8, sys.byteorder))
        try:
            self.map = mmap.mmap(fd, ACK_PAGE, mmap.MAP_SHARED, mmap.PROT_READ)
        except BaseException:
            os.close(fd)
            raise
        self.fd = fd
        self.word = memoryview(self.map)[: 8 * (1 + MAX_LEASES)].cast("Q")

    def read(self) -> int:
        return int(self.word[0])

    def leases(self, granted: int) -> list[int]:
        """The messages the subscriber says it holds, of the first ``granted`` lease words (0s left out):
        whatever it writes there, it protects at most ``granted`` slots."""
        word = self.word
        return [n for n in word[1 : 1 + min(granted, MAX_LEASES)] if n]

    def sent(self) -> None:
        """The page went to its subscriber: our descriptor is no longer needed (the mapping keeps its own)."""
        if self.fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = -1

    def close(self) -> None:
        self.word.release()
        self.map.close()
        self.sent()


class MappedAck:
    """A subscriber's writable mapping of the acknowledgement page its publisher sent; owns ``fd``.

    Raises:
        RemoteProtocolError: the file is not a memfd sealed against resizing, of ``ACK_PAGE`` bytes.
    """

    def __init__(self, fd: int) -> None:
        try:
            try:
                seals = fcntl.fcntl(fd, fcntl.F_GET_SEALS)
            except OSError:
                raise RemoteProtocolError("the publisher sent an acknowledgement page that is not a memfd") from None
            if seals & _REQUIRED != _REQUIRED or os.fstat(fd).st_size != ACK_PAGE:
                raise RemoteProtocolError("the publisher sent an acknowledgement page that is not sealed at 4 KiB")
            try:
                self.map = mmap.mmap(fd, ACK_PAGE, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            except OSError as exc:
                raise RemoteProtocolError(f"cannot map the acknowledgement page: {exc.strerror or exc}") from None
        finally:
            os.close(fd)
        self.word = memoryview(self.map)[: 8 * (1 + MAX_LEASES)].cast("Q")

    def write(self, next_message: int) -> None:
        self.word[0] = next_message

    def lease(self, index: int, message: int) -> None:
        """Lease word ``index`` (1..``MAX_LEASES``) now says ``message`` (0: free). A new lease is written
        before word 0 moves past its message, so the publisher, which reads word 0 first, never sees the
        message read without seeing it leased (x86-64 keeps stores, and loads, in order)."""
        self.word[index] = message

    def close(self) -> None:
        self.word.release()
        self.map.close()
