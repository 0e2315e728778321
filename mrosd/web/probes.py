"""``ProbePool``: the hub's type probes (a service's type, a topic's definition), bounded so no peer can hold them.

A probe is one short TCPROS connection to a peer that may be hostile: a server that accepts and never answers
costs the probe its whole timeout. So:

- at most ``max_total`` probes run at once, and at most ``per_peer`` of them for one peer (a node);
- waiting probes are queued per peer and started round-robin over the peers, one each per turn, a peer seen
  for the first time first: a node that registers 400 services waits behind its own probes, not in front of
  everyone else's, and a newcomer (a service that just appeared) is probed next;
- each probe has a short timeout; a peer that lets one time out is quarantined for ``quarantine`` seconds,
  and so is every address the probe contacted (``Attempt.contact``): its waiting probes fail at once, and new
  ones for it, or for a service at that address under another node's name, fail without a connection;
- a lookup a client is waiting for (rosbridge ``call_service`` without a type) never queues: it runs now within
  its own bound (``lookup``), or fails at once with the reason.

Waiting probes are bounded by the graph (one per topic or service name at most).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TypeVar

from mrosd import backports
from mrosd.errors import MrosError, RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.tcpros import Node
from mrosd.tcpros.subscriber import Subscriber
from mrosd.web.shared import SharedSubscriptions
from mrosd.wire.header import MAX_HEADER_SIZE, ConnectionHeader, decode_connection_header, encode_header

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

__all__ = ["ProbePool", "definition_from_publisher", "service_type", "split_rosrpc"]

T = TypeVar("T")

#: Seconds one probe may take (connect, header exchange, close); a silent peer costs no more.
PROBE_TIMEOUT = 3.0
#: Seconds a lookup a client waits for may take (its call fails with the reason after that).
LOOKUP_TIMEOUT = 2.0
#: Probes in flight at once, and for one peer.
MAX_PROBES = 8
PER_PEER = 2
#: Lookups in flight at once (rosbridge calls without a type), and for one peer.
MAX_LOOKUPS = 8
LOOKUPS_PER_PEER = 2
#: Seconds a peer whose probe timed out is not probed again.
QUARANTINE = 30.0
#: Quarantined peers remembered (the oldest entries go first beyond this).
MAX_QUARANTINED = 4096


class Attempt:
    """One probe's contacts: ``contact(address)`` before connecting to a peer's address (refused while the
    address is quarantined); a probe that times out quarantines every address it contacted."""

    __slots__ = ("_pool", "addresses")

    def __init__(self, pool: ProbePool) -> None:
        self._pool = pool
        self.addresses: list[str] = []

    def contact(self, address: str) -> None:
        """Raises: MrosError: the address is quarantined."""
        reason = self._pool.quarantine_reason(address)
        if reason:
            raise MrosError(reason)
        self.addresses.append(address)


@dataclass(slots=True)
class _Job:
    key: str
    peer: str
    run: Callable[[Attempt], Awaitable[None]]
    fail: Callable[[str], None]


class ProbePool:
    """Runs probe jobs with global and per-peer bounds, a timeout each, and per-peer round-robin queues."""

    def __init__(
        self,
        *,
        max_total: int = MAX_PROBES,
        per_peer: int = PER_PEER,
        timeout: float = PROBE_TIMEOUT,
        lookup_timeout: float = LOOKUP_TIMEOUT,
        quarantine: float = QUARANTINE,
    ) -> None:
        self.max_total = max_total
        self.per_peer = per_peer
        self.timeout = timeout
        self.lookup_timeout = lookup_timeout
        self.quarantine = quarantine
        self._waiting: dict[str, collections.OrderedDict[str, _Job]] = {}
        #: key -> peer of every waiting probe
        self._where: dict[str, str] = {}
        self._turns: collections.deque[str] = collections.deque()
        self._running: dict[str, asyncio.Task[None]] = {}
        self._active: collections.Counter[str] = collections.Counter()
        self._lookups: collections.Counter[str] = collections.Counter()
        self._quarantined: dict[str, float] = {}

    # --- background probes -----------------------------------------------------------------------

    def submit(
        self, peer: str, key: str, run: Callable[[Attempt], Awaitable[None]], fail: Callable[[str], None]
    ) -> None:
        """Queue ``run(attempt)`` for ``peer`` unless ``key`` is already waiting or running; ``fail(reason)`` is called
        instead when the peer is quarantined, the probe times out or raises ``MrosError``/``OSError``."""
        if key in self._running or key in self._where:
            return
        reason = self.quarantine_reason(peer)
        if reason:
            fail(reason)
            return
        queue = self._waiting.get(peer)
        if queue is None:
            queue = self._waiting[peer] = collections.OrderedDict()
            if peer not in self._turns and peer not in self._active:
                self._turns.appendleft(peer)  # a newcomer goes first: a flood of old peers cannot bury it
        queue[key] = _Job(key, peer, run, fail)
        self._where[key] = peer
        if peer not in self._turns:
            self._turns.append(peer)
        self._pump()

    def discard(self, key: str) -> None:
        """Forget a waiting probe (its name left the graph); a running one finishes."""
        peer = self._where.pop(key, None)
        queue = self._waiting.get(peer) if peer is not None else None
        if queue is not None:
            queue.pop(key, None)
            if not queue:
                del self._waiting[peer]  # type: ignore[arg-type]

    def running(self, key: str) -> asyncio.Task[None] | None:
        return self._running.get(key)

    def in_flight(self) -> list[str]:
        """Keys of the probes running now."""
        return list(self._running)

    def waiting(self) -> int:
        return sum(len(q) for q in self._waiting.values())

    def _pump(self) -> None:
        loop = asyncio.get_running_loop()
        skipped = 0
        while len(self._running) < self.max_total and self._turns and skipped < len(self._turns):
            peer = self._turns.popleft()
            queue = self._waiting.get(peer)
            if not queue:
                self._waiting.pop(peer, None)
                continue
            if self._active[peer] >= self.per_peer:
                self._turns.append(peer)  # its turn comes back when one of its probes ends
                skipped += 1
                continue
            skipped = 0
            key, job = queue.popitem(last=False)
            del self._where[key]
            if queue:
                self._turns.append(peer)
            else:
                del self._waiting[peer]
            self._active[peer] += 1
            self._running[job.key] = loop.create_task(self._run(job), name=f"web probe {job.key}")

    async def _run(self, job: _Job) -> None:
        attempt = Attempt(self)
        try:
            async with backports.timeout(self.timeout):
                await job.run(attempt)
        except TimeoutError:
            self._quarantine(job.peer, *attempt.addresses)
            job.fail(f"{job.peer} did not answer within {self.timeout:g} s")
        except (MrosError, OSError) as exc:
            job.fail(str(exc) or type(exc).__name__)
        except Exception:
            log.exception("web: probe %s failed", job.key)
            job.fail("internal error")
        finally:
            self._running.pop(job.key, None)
            self._active[job.peer] -= 1
            if self._active[job.peer] <= 0:
                del self._active[job.peer]
            if job.peer in self._waiting and job.peer not in self._turns:
                self._turns.append(job.peer)
            self._pump()

    # --- quarantine --------------------------------------------------------------------------------

    def _quarantine(self, peer: str, *addresses: str) -> None:
        until = time.monotonic() + self.quarantine
        for name in (peer, *addresses):
            self._quarantined.pop(name, None)
            self._quarantined[name] = until
        while len(self._quarantined) > MAX_QUARANTINED:
            del self._quarantined[next(iter(self._quarantined))]
        _ratelog.warning(
            "quarantine",
            "web: %s (%s) let a type probe time out: not probed for %g s",
            peer,
            ", ".join(addresses) or "no address",
            self.quarantine,
        )
        queue = self._waiting.pop(peer, None)
        if queue:
            for key in queue:
                self._where.pop(key, None)
            reason = self.quarantine_reason(peer)
            for job in queue.values():
                job.fail(reason)

    def quarantine_reason(self, peer: str) -> str:
        """Why ``peer`` (a node or an address) is not probed now; empty when it may be."""
        until = self._quarantined.get(peer)
        if until is None:
            return ""
        left = until - time.monotonic()
        if left <= 0:
            del self._quarantined[peer]
            return ""
        return f"{peer} did not answer a type probe in time (not probed again for {left:.0f} s)"

    # --- lookups a client waits for ------------------------------------------------------------------

    async def lookup(self, peer: str, run: Callable[[Attempt], Awaitable[T]]) -> T:
        """``await run(attempt)`` now, within ``lookup_timeout``, outside the queue of background probes.

        Raises:
            MrosError: the peer is quarantined or already has its share of lookups in flight, or too many are.
            TimeoutError: no answer in time (the peer is quarantined).
            OSError: as ``run`` raises it.
        """
        reason = self.quarantine_reason(peer)
        if reason:
            raise MrosError(reason)
        if self._lookups[peer] >= LOOKUPS_PER_PEER or sum(self._lookups.values()) >= MAX_LOOKUPS:
            raise MrosError(f"too many type lookups in flight for {peer}: give the type in the call")
        self._lookups[peer] += 1
        attempt = Attempt(self)
        try:
            async with backports.timeout(self.lookup_timeout):
                return await run(attempt)
        except TimeoutError:
            self._quarantine(peer, *attempt.addresses)
            raise TimeoutError(f"{peer} did not answer a type probe within {self.lookup_timeout:g} s") from None
        finally:
            self._lookups[peer] -= 1
            if self._lookups[peer] <= 0:
                del self._lookups[peer]

    async def aclose(self) -> None:
        self._waiting.clear()
        self._where.clear()
        self._turns.clear()
        tasks = list(self._running.values())
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


# --- the probes themselves (their caller bounds their time) ------------------------------------------


def split_rosrpc(uri: str) -> tuple[str, int]:
    """``rosrpc://host:port`` -> ``(host, port)`` (IPv6 brackets removed).

    Raises:
        MrosError: not a rosrpc URI with a port.
    """
    if not uri.startswith("rosrpc://"):
        raise MrosError(f"not a rosrpc URI: {uri!r}")
    host, _, port = uri[len("rosrpc://") :].rstrip("/").rpartition(":")
    if not host or not port.isdigit():
        raise MrosError(f"not a rosrpc URI: {uri!r}")
    return host.strip("[]"), int(port)


async def service_type(node: Node, name: str, attempt: Attempt) -> str:
    """Ask service ``name`` its type with a ``probe=1`` connection header, as roscpp's tools do.

    Raises:
        MrosError: the master does not know it, its address is quarantined, or its server refused the probe
            or sent no type.
        OSError: its server could not be reached.
    """
    uri = await node.master.lookup_service(name)
    host, port = split_rosrpc(uri)
    attempt.contact(f"{host}:{port}")
    reader, writer = await asyncio.open_connection(host, port)
    try:
        writer.write(encode_header(ConnectionHeader(callerid=node.name, service=name, md5sum="*", probe="1")))
        size = int.from_bytes(await reader.readexactly(4), "little")
        if size > MAX_HEADER_SIZE:
            raise RemoteProtocolError(f"service {name}: header of {size} bytes")
        header = decode_connection_header(await reader.readexactly(size))
    except asyncio.IncompleteReadError:
        raise RemoteProtocolError(f"service {name} closed the probe without a header") from None
    finally:
        writer.close()
    if header.error:
        raise RemoteProtocolError(f"service {name} refused the probe: {header.error}")
    if not header.type:
        raise RemoteProtocolError(f"service {name} did not say its type")
    return header.type


async def definition_from_publisher(subs: SharedSubscriptions, topic: str, timeout: float) -> str | None:
    """A publisher's message_definition of ``topic``, from its connection header: through the topic's shared
    subscription when it has one, else a subscription of its own closed at once.

    Raises:
        TimeoutError: no publisher connected within ``timeout`` seconds.
        MrosError: the master refused the subscription.
    """
    entry = subs.entries.get(topic)
    if entry is not None:
        return await _header_definition(entry.subscriber, timeout)
    sub = await subs.subscribe(topic)
    try:
        return await _header_definition(sub, timeout)
    finally:
        await sub.aclose()  # a client's shared subscription waits for this one to end (WebHub._unprobe)


async def _header_definition(sub: Subscriber, timeout: float) -> str | None:
    await sub.wait_for_publishers(1, timeout=timeout)
    for link in sub.links.values():
        if link.header is not None and link.header.message_definition:
            return link.header.message_definition
    return None
