"""A graph that cleans itself: unregister nodes whose slave API refuses connections.

rosmaster keeps a dead node's registrations forever (``rosnode cleanup`` by hand). Every
``interval`` seconds the ``GraphCleaner`` task opens a plain TCP connection to each registered
slave API. Only a refused connection (ECONNREFUSED on every address of the host: nothing listens
there any more) makes a node a suspect; a timeout, a reset or an unresolvable host never does, so
a node that is slow, stopped (SIGSTOP: the kernel still accepts its connections) or behind a
flaky network is left alone. A suspect is confirmed at once with ``getPid`` over a fresh
connection: still refused, or answered with another pid than the one the node reported earlier
(its port was reused), and the node is removed with the publisherUpdates that implies and one log
line, unless it registered again meanwhile. Any other answer keeps it.

``judge`` is the pure decision; ``GraphCleaner`` is the small asyncio task around it. Probes run
concurrently (bounded) with timeouts, so the master never waits on a node.
"""

from __future__ import annotations

import asyncio
import enum
import errno
import logging
import socket
from collections.abc import Callable
from urllib.parse import urlsplit

from mrosd import backports
from mrosd.errors import XmlRpcError
from mrosd.master.registry import NodeEntry, Notification, Registry
from mrosd.xmlrpc import XmlRpcClient

log = logging.getLogger(__name__)

#: Seconds between two sweeps of the graph (the default of ``Master``/``MasterApi``).
DEFAULT_CLEANUP_INTERVAL = 5.0
#: Caller id the master uses for its own calls.
MASTER_CALLER_ID = "/master"


class Probe(enum.Enum):
    """The outcome of one attempt to reach a slave API."""

    ANSWERED = "answered"
    REFUSED = "refused"
    NO_ANSWER = "no answer"  # timeout, reset, unreachable, bad reply: says nothing about the node


def judge(connect: Probe, confirm: Probe | None, pid: int | None, known_pid: int | None) -> bool:
    """Whether a node is dead: its connection was refused and ``getPid`` confirmed it.

    Args:
        connect: the TCP connection attempt.
        confirm: the ``getPid`` call made after a refusal (None when none was made).
        pid: the pid ``getPid`` answered, if it answered.
        known_pid: the pid the node reported in an earlier sweep, if any.
    """
    if connect is not Probe.REFUSED:
        return False
    if confirm is Probe.REFUSED:
        return True
    return confirm is Probe.ANSWERED and pid is not None and known_pid is not None and pid != known_pid


def _refused(exc: BaseException | None) -> bool:
    """Whether ``exc`` or an exception it was raised from is a refused connection."""
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, ConnectionRefusedError) or (isinstance(exc, OSError) and exc.errno == errno.ECONNREFUSED):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


async def probe_connect(api: str, timeout: float) -> Probe:
    """Try a TCP connection to every address of ``api``'s host; REFUSED only if each one refuses."""
    try:
        parts = urlsplit(api)
        host, port = parts.hostname, parts.port
    except ValueError:
        return Probe.NO_ANSWER
    if not host or not port:
        return Probe.NO_ANSWER
    loop = asyncio.get_running_loop()
    try:
        async with backports.timeout(timeout):
            infos = await loop.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, TimeoutError):
        return Probe.NO_ANSWER
    refused = 0
    for _family, _type, _proto, _name, address in infos:
        try:
            async with backports.timeout(timeout):
                _reader, writer = await asyncio.open_connection(str(address[0]), port)
        except ConnectionRefusedError:
            refused += 1
            continue
        except (OSError, TimeoutError):
            continue
        writer.close()
        try:
            await writer.wait_closed()
        except OSError:
            pass
        return Probe.ANSWERED
    return Probe.REFUSED if infos and refused == len(infos) else Probe.NO_ANSWER


async def probe_get_pid(api: str, timeout: float) -> tuple[Probe, int | None]:
    """``getPid`` over a fresh connection (a pooled one may be stale): the outcome and the pid."""
    client = XmlRpcClient(timeout=timeout)
    try:
        reply = await client.call(api, "getPid", MASTER_CALLER_ID, timeout=timeout)
    except XmlRpcError as exc:
        if _refused(exc):
            return Probe.REFUSED, None
        # Some clients report a refusal on several addresses without an errno: ask the socket.
        if await probe_connect(api, timeout) is Probe.REFUSED:
            return Probe.REFUSED, None
        return Probe.NO_ANSWER, None
    except Exception:
        return Probe.NO_ANSWER, None
    finally:
        await client.aclose()
    if isinstance(reply, list | tuple) and len(reply) == 3 and reply[0] == 1 and type(reply[2]) is int:
        return Probe.ANSWERED, reply[2]
    return Probe.ANSWERED, None


class GraphCleaner:
    """Periodically removes nodes whose slave API refuses connections (see the module docstring).

    Args:
        registry: the master's registry (mutated only from the event loop, between awaits).
        submit: where the resulting publisherUpdates go (the notifier).
        interval: seconds between sweeps.
        timeout: seconds allowed for one connection attempt or getPid call.
        concurrency: most slave APIs probed at the same time.
    """

    def __init__(
        self,
        registry: Registry,
        submit: Callable[[list[Notification]], None],
        interval: float = DEFAULT_CLEANUP_INTERVAL,
        *,
        timeout: float = 2.0,
        concurrency: int = 32,
    ) -> None:
        self.registry = registry
        self.submit = submit
        self.interval = interval
        self.timeout = min(timeout, max(interval / 2, 0.05))
        self._slots = asyncio.Semaphore(concurrency)
        #: pid each slave API reported (learned once per URI, forgotten when the URI leaves the graph).
        self.pids: dict[str, int] = {}
        self.removed = 0

    async def run(self) -> None:
        """Sweep every ``interval`` seconds until cancelled."""
        while True:
            await asyncio.sleep(self.interval)
            try:
                await self.sweep()
            except asyncio.CancelledError:
                raise
            except Exception:  # pragma: no cover - a bug here must not stop future sweeps
                log.exception("graph cleanup sweep failed")

    async def sweep(self) -> list[str]:
        """Probe every registered slave API once; returns the names of the nodes removed."""
        apis = self.registry.apis()
        for api in [a for a in self.pids if a not in apis]:
            del self.pids[api]
        results = await asyncio.gather(*(self._check(api) for api in apis))
        return [name for names in results for name in names]

    async def _check(self, api: str) -> list[str]:
        async with self._slots:
            entries = self._entries(api)
            connect = await probe_connect(api, self.timeout)
            if connect is Probe.ANSWERED:
                if api not in self.pids:
                    outcome, pid = await probe_get_pid(api, self.timeout)
                    if outcome is Probe.ANSWERED and pid is not None:
                        self.pids[api] = pid
                return []
            if connect is not Probe.REFUSED:
                return []
            confirm, pid = await probe_get_pid(api, self.timeout)
            if not judge(connect, confirm, pid, self.pids.get(api)):
                return []
        return self._remove(api, entries, confirm, pid)

    def _entries(self, api: str) -> list[tuple[NodeEntry, int]]:
        return [(n, n.generation) for n in self.registry.nodes.values() if n.api == api]

    def _remove(self, api: str, before: list[tuple[NodeEntry, int]], confirm: Probe, pid: int | None) -> list[str]:
        removed = []
        for entry, generation in before:
            # Registered again (same URI) or replaced (new URI) while we probed: it is alive.
            if self.registry.nodes.get(entry.name) is not entry or entry.generation != generation:
                continue
            counts = (len(entry.publications), len(entry.subscriptions), len(entry.services))
            self.submit(self.registry.remove_node(entry.name))
            removed.append(entry.name)
            self.removed += 1
            why = "refuses connections" if confirm is Probe.REFUSED else f"is now another process (pid {pid})"
            log.warning(
                "removed dead node %s: its slave API %s %s (%d publications, %d subscriptions, %d services)",
                entry.name,
                api,
                why,
                *counts,
            )
        self.pids.pop(api, None)
        return removed
