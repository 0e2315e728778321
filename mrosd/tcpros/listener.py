"""A node's TCPROS accept loop: admission at accept time, and a listener that backs off at the fd limit.

Why not ``loop.create_server``: asyncio's accept loop (3.11) answers EMFILE by logging a traceback and
re-arming a retry for every remaining slot of its accept batch, so a flood at the descriptor limit spins
the node and writes hundreds of thousands of log lines; uvloop (libuv) answers it by accepting and closing
every queued connection, a legitimate subscriber's included. Neither lets the node choose whom to drop.

So the node accepts itself (``add_reader`` on its listening socket, on either loop), and:
  * every accepted connection is admitted by ``HeaderAdmission`` before a protocol allocates anything
    (waiting-for-header caps per node and per address, oldest shed first; a header deadline);
  * running out of descriptors is seen before it happens: ``accept`` returns the lowest free descriptor,
    so an accepted fd at or above ``limit - reserve`` means every one below it is taken. Then, and on an
    actual EMFILE/ENFILE, the listener pauses, sheds the oldest quarter of the header-less connections
    (established subscribers keep their data) and resumes after a short, growing delay;
  * every line an outsider can cause is rate-limited (one per interval, with the count suppressed).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import resource
import socket
from collections.abc import Callable

from mrosd.lograte import RateLimitedLog
from mrosd.tcpros.admission import AdmissionLimits, HeaderAdmission

__all__ = ["ACCEPT_BATCH", "AdmittedConnection", "TcprosListener", "fd_reserve"]

log = logging.getLogger(__name__)
#: One line per kind per ten seconds, with the count of those suppressed: a flood is reported, not echoed.
rate_log = RateLimitedLog(log, period=10.0, burst=1)

#: Connections accepted per readiness event: small enough that a legitimate peer's header is read before
#: many newer connections can push it out of the waiting caps.
ACCEPT_BATCH = 16

#: Errors of ``accept`` that mean the process or the system is out of a resource, not that a peer failed.
_EXHAUSTED = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})

#: Pause of the listener after a shortage, doubled while shortages follow each other, up to the maximum.
PAUSE_MIN = 0.05
PAUSE_MAX = 1.0

#: Pause after every ACCEPT_BATCH accepts that had to shed a waiting connection (a cap was full: a flood,
#: most likely). A flooder that reconnects whatever it loses otherwise keeps the node accepting and shedding
#: at full speed (half a CPU on asyncio or uvloop); this bounds it to ACCEPT_BATCH per pause (1600/s) while the
#: kernel's queue (1024 long), served in order, still reaches a legitimate peer behind a full queue of flood
#: connections in well under a second. Accepts that shed nothing are never slowed.
FLOOD_PAUSE = 0.01


def fd_reserve(soft_limit: int) -> int:
    """Descriptors an accept loop leaves free for the rest of the process (slave API, master calls, files)."""
    return min(64, max(8, soft_limit // 16))


def _watermark() -> int:
    """The lowest descriptor number that means "within the reserve" (0: no limit to watch)."""
    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return 0 if soft == resource.RLIM_INFINITY else soft - fd_reserve(soft)


class AdmittedConnection(asyncio.BaseProtocol):
    """What the listener asks of the protocols it creates, beyond asyncio's protocol interface."""

    def shed(self, reason: str) -> None:
        """Close at once (or as soon as connected): the listener dropped this connection."""
        raise NotImplementedError


class TcprosListener:
    """Accepts TCPROS connections for one node; protocols report back through ``header_bytes``,
    ``header_done`` and ``closed``.

    Args:
        factory: makes the protocol of one accepted connection.
        limits: the admission caps and the header deadline.
        name: the node's name, for log lines.
    """

    def __init__(
        self, factory: Callable[[], AdmittedConnection], limits: AdmissionLimits | None = None, name: str = ""
    ) -> None:
        self._factory = factory
        self.admission: HeaderAdmission[AdmittedConnection] = HeaderAdmission(limits)
        self.name = name
        self.port = 0
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._reading = False
        self._resume: asyncio.TimerHandle | None = None
        self._deadline: asyncio.TimerHandle | None = None
        self._pause = PAUSE_MIN
        self._watermark = 0
        self._connecting: set[asyncio.Task[None]] = set()
        self._flood_sheds = 0
        #: shortages seen (EMFILE/ENFILE or the watermark), for tests and stats
        self.shortages = 0

    @property
    def limits(self) -> AdmissionLimits:
        return self.admission.limits

    def start(self, host: str, port: int = 0, backlog: int = 1024) -> int:
        """Bind, listen and start accepting on the running loop; return the bound port.

        Raises:
            OSError: the address cannot be bound.
        """
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.create_server((host, port), family=family, backlog=backlog)
        sock.setblocking(False)
        self._sock = sock
        self._loop = asyncio.get_running_loop()
        self.port = int(sock.getsockname()[1])
        self._watermark = _watermark()
        self._start_reading()
        return self.port

    async def aclose(self) -> None:
        """Stop accepting, close the listening socket, and let connections already accepted reach their
        protocols (bounded), so the caller can close them with the rest."""
        loop = self._loop
        self._stop_reading()
        for handle in (self._resume, self._deadline):
            if handle is not None:
                handle.cancel()
        self._resume = self._deadline = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self._connecting and loop is not None:
            await asyncio.wait(list(self._connecting), timeout=1.0)
            for task in list(self._connecting):
                task.cancel()

    # --- reports from the protocols --------------------------------------------------------------

    def header_bytes(self, conn: AdmittedConnection, buffered: int) -> None:
        """``conn`` holds ``buffered`` bytes of an incomplete header."""
        for victim in self.admission.received(conn, buffered):
            self._shed(victim, "waiting headers over their byte budget")

    def header_done(self, conn: AdmittedConnection) -> None:
        self.admission.header_done(conn)

    def closed(self, conn: AdmittedConnection) -> None:
        self.admission.closed(conn)

    # --- accepting -------------------------------------------------------------------------------

    def _start_reading(self) -> None:
        if self._sock is not None and self._loop is not None and not self._reading:
            self._loop.add_reader(self._sock.fileno(), self._on_readable)
            self._reading = True

    def _stop_reading(self) -> None:
        if self._reading and self._sock is not None and self._loop is not None:
            self._loop.remove_reader(self._sock.fileno())
        self._reading = False

    def _on_readable(self) -> None:
        sock = self._sock
        if sock is None:
            return
        for _ in range(ACCEPT_BATCH):
            if not self._reading:  # paused by what the last connection caused
                return
            try:
                conn, addr = sock.accept()
            except (BlockingIOError, InterruptedError):
                self._pause = PAUSE_MIN
                return
            except ConnectionAbortedError:
                continue
            except OSError as exc:
                if exc.errno in _EXHAUSTED:
                    self._shortage(f"accept failed: {exc.strerror}")
                else:
                    rate_log.warning(self.name + ":accept", "%s: TCPROS accept failed: %s", self.name, exc)
                    self._pause_for(PAUSE_MAX)
                return
            if self._watermark and conn.fileno() >= self._watermark:
                self._shortage(f"descriptor {conn.fileno()} is within the reserve", conn, addr)
                return
            self._admit(conn, addr)

    def _admit(self, conn: socket.socket, addr: object) -> None:
        loop = self._loop
        assert loop is not None
        host = str(addr[0]) if isinstance(addr, tuple) and addr else "?"
        proto = self._factory()
        verdict = self.admission.admit(proto, host, loop.time())
        for victim in verdict.shed:
            self._shed(victim, "too many connections waiting for a header; the oldest goes first")
        if verdict.shed:
            self._flood_sheds += 1
            if self._flood_sheds % ACCEPT_BATCH == 0:
                self._pause_for(FLOOD_PAUSE)
        if not verdict.admitted:
            conn.close()
            rate_log.warning(
                self.name + ":full", "%s: refusing TCPROS connections: %d open", self.name, self.admission.connections
            )
            return
        conn.setblocking(False)
        task = loop.create_task(self._connect(conn, proto))
        self._connecting.add(task)
        task.add_done_callback(self._connecting.discard)
        self._arm_deadline()

    async def _connect(self, conn: socket.socket, proto: AdmittedConnection) -> None:
        loop = self._loop
        assert loop is not None
        try:
            await loop.connect_accepted_socket(lambda: proto, conn)
        except BaseException as exc:
            conn.close()
            self.admission.closed(proto)
            if not isinstance(exc, (OSError, asyncio.CancelledError)):
                raise

    def _shortage(self, why: str, conn: socket.socket | None = None, addr: object = None) -> None:
        """Out of descriptors (or about to be): pause accepting, shed the oldest header-less connections.

        ``conn`` (accepted at the watermark) is admitted when others made room for it, else closed: the
        descriptors below the limit are the node's own reserve.
        """
        self.shortages += 1
        self._watermark = _watermark()  # the limit may have been raised since start()
        shed = self.admission.shed_oldest()
        # Shedding frees descriptors a loop turn later: a short pause. With nobody to shed, only our own
        # connections can free them: wait longer each time, up to PAUSE_MAX.
        delay = PAUSE_MIN if shed else self._pause
        self._pause = PAUSE_MIN if shed else min(self._pause * 2, PAUSE_MAX)
        rate_log.warning(
            self.name + ":shortage",
            "%s: TCPROS listener out of descriptors (%s): paused %.2f s, shed %d header-less connection(s)",
            self.name,
            why,
            delay,
            len(shed),
        )
        self._pause_for(delay)  # before admitting: the admission's own short pause must not replace it
        for victim in shed:
            self._shed(victim, "out of descriptors", quiet=True)
        if conn is not None:
            if shed:
                self._admit(conn, addr)
            else:
                conn.close()

    def _pause_for(self, delay: float) -> None:
        if self._loop is None or self._resume is not None:
            return
        self._stop_reading()
        self._resume = self._loop.call_later(delay, self._resumed)

    def _resumed(self) -> None:
        self._resume = None
        self._start_reading()

    def _shed(self, conn: AdmittedConnection, reason: str, *, quiet: bool = False) -> None:
        log.debug("%s: shedding a TCPROS connection: %s", self.name, reason)
        if not quiet:
            rate_log.warning(self.name + ":shed", "%s: dropping TCPROS connections: %s", self.name, reason)
        with contextlib.suppress(Exception):
            conn.shed(reason)

    # --- header deadlines ------------------------------------------------------------------------

    def _arm_deadline(self) -> None:
        if self._deadline is not None or self._loop is None:
            return
        due = self.admission.next_deadline()
        if due is not None:
            self._deadline = self._loop.call_at(due, self._expire)

    def _expire(self) -> None:
        self._deadline = None
        assert self._loop is not None
        expired = self.admission.expired(self._loop.time())
        if expired:
            rate_log.warning(
                self.name + ":deadline",
                "%s: closing %d TCPROS connection(s) that sent no complete header within %.1f s",
                self.name,
                len(expired),
                self.limits.header_timeout,
            )
        for victim in expired:
            self._shed(victim, "no connection header in time", quiet=True)
        self._arm_deadline()
