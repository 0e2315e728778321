"""The fleet bridge: one Zenoh session and one local node that carry chosen topics and services across.

``FleetBridge`` owns the session and the shared state (``link.FleetLink``) and runs the parts, each in its
module: local topics offered to the fleet (``sending``), remote topics published here with every body
checked (``receiving``), services both ways (``services``), and what peers announce (``discovery``). Two
loops drive them: a look at the local graph every half second, and a periodic check of silent items and of
which remote topics a local node subscribes to.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable
from typing import Any

from mrosd import backports
from mrosd.errors import ConfigError, MrosError
from mrosd.fleet.discovery import Discovery
from mrosd.fleet.handoff import Inbox, Outbox
from mrosd.fleet.keys import ANNOUNCE_PERIOD, discovery_subscription
from mrosd.fleet.limits import INBOX_BYTES, INBOX_BYTES_EACH
from mrosd.fleet.link import Counters, FleetLink, ReceivedService, ReceivedTopic, SentService, SentTopic, ratelog
from mrosd.fleet.options import FleetOptions, zenoh_settings
from mrosd.fleet.presence import Presence
from mrosd.fleet.raw import require_zenoh
from mrosd.fleet.receiving import Receiver
from mrosd.fleet.sending import Sender
from mrosd.fleet.services import MAX_INFLIGHT_CALLS, Services
from mrosd.tcpros.admission import AdmissionLimits
from mrosd.tcpros.node import Node

__all__ = ["FleetBridge", "fleet_admission", "fleet_sessions", "require_zenoh"]

log = logging.getLogger(__name__)

#: Seconds between two looks at the local graph, and between two checks of what must be subscribed.
GRAPH_PERIOD = 0.5
TICK_PERIOD = 0.25
#: The inbox's name for announcements, and how many may wait for the loop (each item repeats every second, so
#: one lost in a burst comes again; a flood of names costs this many strings at most).
DISCOVERY = "@discovery"
DISCOVERY_QUEUE = 4096
#: The fleet node's service that answers its status as JSON.
STATUS_SERVICE = "~status"


def fleet_admission(fd_budget: int) -> AdmissionLimits:
    """Inbound TCPROS caps of the fleet's node from its descriptor budget (``mrosd.fdbudget``): half of it for
    local subscribers and callers of what it receives. Of the other half, a quarter of the budget caps the
    service calls in flight (one connection each) and a quarter the Zenoh sessions (``fleet_sessions``); the
    local publishers of what it sends come out of the TCPROS reserve of the daemon."""
    cap = max(1, fd_budget // 2)
    return AdmissionLimits(
        max_connections=cap, max_pending=max(1, min(256, cap // 2)), max_pending_per_address=max(1, min(128, cap // 4))
    )


def fleet_sessions(fd_budget: int) -> int:
    """Zenoh sessions (peers linked to this one, one socket each) the fleet's budget allows."""
    return max(1, fd_budget // 4)


class FleetBridge:
    """``async with FleetBridge(options, master_uri):`` links this master to the fleet until closed.

    ``fd_budget`` (the daemon's share for the fleet, ``mrosd.fdbudget``) caps its node's inbound connections,
    its service calls in flight and the Zenoh sessions linked to it.

    Raises (from ``start``):
        ConfigError: eclipse-zenoh is missing or the options are refused by Zenoh.
        MasterUnreachableError: the local master does not answer.
    """

    def __init__(
        self,
        options: FleetOptions,
        master_uri: str,
        *,
        node_name: str = "mrosd_fleet",
        host: str | None = None,
        fd_budget: int | None = None,
    ) -> None:
        admission = fleet_admission(fd_budget) if fd_budget is not None else None
        node = Node(node_name, master_uri, argv=[], host=host, rosout=False, logger_services=False, admission=admission)
        self.link = FleetLink(options, node)
        max_calls = MAX_INFLIGHT_CALLS if fd_budget is None else min(MAX_INFLIGHT_CALLS, max(1, fd_budget // 4))
        self.sender = Sender(self.link)
        self.receiver = Receiver(self.link)
        self.services = Services(self.link, max_calls)
        self.discovery = Discovery(self.link, self.receiver, self.services)
        self.master_uri = master_uri
        self.fd_budget = fd_budget
        self._tasks: list[asyncio.Task[None]] = []
        self._discovery_sub: Any = None

    # --- the shared state, as callers and tests read it -------------------------------------------

    @property
    def options(self) -> FleetOptions:
        return self.link.options

    @property
    def node(self) -> Node:
        return self.link.node

    @property
    def session(self) -> Any:
        return self.link.session

    @property
    def sent(self) -> dict[str, SentTopic]:
        return self.link.sent

    @property
    def received(self) -> dict[str, ReceivedTopic]:
        return self.link.received

    @property
    def sent_services(self) -> dict[str, SentService]:
        return self.link.sent_services

    @property
    def received_services(self) -> dict[str, ReceivedService]:
        return self.link.received_services

    @property
    def presence(self) -> Presence:
        return self.link.presence

    @property
    def counters(self) -> Counters:
        return self.link.counters

    # --- lifecycle ---------------------------------------------------------------------------------

    async def start(self) -> None:
        link = self.link
        zenoh = link.zenoh = require_zenoh()
        config = zenoh.Config()
        try:
            for path, value in zenoh_settings(link.options):
                config.insert_json5(path, value)
            if self.fd_budget is not None:
                config.insert_json5("transport/unicast/max_sessions", str(fleet_sessions(self.fd_budget)))
        except Exception as exc:
            raise ConfigError(f"fleet: Zenoh refused the configuration: {exc}") from exc
        loop = asyncio.get_running_loop()
        await link.node.start()
        try:
            try:
                # zenoh.open waits for the first connection attempts: off the loop.
                link.session = await asyncio.to_thread(zenoh.open, config)
            except Exception as exc:
                raise ConfigError(f"fleet: cannot open the Zenoh session: {exc}") from exc
            link.inbox = Inbox(
                loop,
                self._deliver,
                link.options.queue_size,
                {DISCOVERY: DISCOVERY_QUEUE},
                max_bytes=INBOX_BYTES,
                max_bytes_each=INBOX_BYTES_EACH,
            )
            announce = {
                "congestion_control": zenoh.CongestionControl.DROP,
                "priority": zenoh.Priority.BACKGROUND,
                "allowed_destination": zenoh.Locality.REMOTE,
            }
            link.outbox = Outbox(link.session, link.options.queue_size, announce)
            link.outbox.start()
            self._discovery_sub = link.session.declare_subscriber(
                discovery_subscription(),
                lambda sample: link.inbox_put(DISCOVERY, str(sample.key_expr)),
                allowed_origin=zenoh.Locality.REMOTE,
            )
            await self._advertise_status()
        except BaseException:
            await self.aclose()
            raise
        self._tasks = [
            asyncio.create_task(self._graph_loop(), name="fleet-graph"),
            asyncio.create_task(self._tick_loop(), name="fleet-tick"),
        ]
        log.info("fleet: robot %s on Zenoh %s (%s)", link.options.robot, link.session.zid(), link.options.mode)

    async def aclose(self) -> None:
        link = self.link
        if link.closed:
            return
        link.closed = True
        tasks = [*self._tasks, *link.background]
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if link.inbox is not None:
            link.inbox.closed = True
        if link.outbox is not None:
            await asyncio.to_thread(link.outbox.close)
        for st in list(link.sent.values()):
            await self.sender.drop(st)
        for rt in list(link.received.values()):
            await self.receiver.drop(rt)
        await self.services.aclose()
        link.undeclare(self._discovery_sub)
        if link.session is not None:
            await asyncio.to_thread(link.session.close)
        await link.node.aclose()

    async def __aenter__(self) -> FleetBridge:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def wait_until(self, predicate: Callable[[], bool], timeout: float) -> None:
        """Return once ``predicate()`` holds, checked after every change of the bridge.

        Raises:
            TimeoutError: it did not hold within ``timeout`` seconds.
        """
        changed = self.link.changed
        async with backports.timeout(timeout):
            while not predicate():
                changed.clear()
                await changed.wait()

    def _deliver(self, name: str, items: list[Any]) -> None:
        if name == DISCOVERY:
            self.discovery.heard(items)
        else:
            self.receiver.deliver(name, items)

    # --- the two loops -----------------------------------------------------------------------------

    async def _graph_loop(self) -> None:
        master = self.link.node.master
        while True:
            try:
                pubs, _subs, srvs = await master.call("getSystemState")
                types = dict(await master.call("getTopicTypes"))
                await self.sender.reconcile(pubs, types)
                await self.services.reconcile(srvs)
                self.link.announce()
            except asyncio.CancelledError:
                raise
            except (MrosError, OSError, ValueError, TypeError) as exc:
                ratelog.warning("graph", "fleet: cannot read the local graph: %s", exc)
            await asyncio.sleep(GRAPH_PERIOD)

    async def _tick_loop(self) -> None:
        while True:
            await asyncio.sleep(TICK_PERIOD)
            try:
                await self.discovery.expire()
                if self.receiver.follow_subscribers():
                    self.link.announce()
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("fleet: periodic check failed")

    # --- status ----------------------------------------------------------------------------------

    async def _advertise_status(self) -> None:
        """``~status`` (std_srvs/Trigger): ``status()`` as JSON in ``message``; what ``mros fleet status`` reads.

        A ROS service, so any tool (``rosservice call /mrosd_fleet/status``) and any host that reaches the
        master can ask, with no extra port or protocol.
        """
        from mrosd.msg import get_service_class

        trigger = get_service_class("std_srvs/Trigger")  # vendored with mrosd: no peer's definition

        def answer(_request: Any) -> Any:
            return trigger._response_class(success=True, message=json.dumps(self.status()))

        await self.link.node.advertise_service(STATUS_SERVICE, trigger, answer)

    def status(self) -> dict[str, Any]:
        """Peers, links and per-topic counts, as ``mros fleet status`` prints them (plain data)."""
        link = self.link
        now = time.monotonic()
        peers: list[str] = []
        if link.session is not None:
            with contextlib.suppress(Exception):
                peers = [str(z) for z in link.session.info.peers_zid()]
        outbox, inbox, counters = link.outbox, link.inbox, link.counters
        return {
            "robot": link.options.robot,
            "mode": link.options.mode,
            "zid": str(link.session.zid()) if link.session is not None else "",
            "peers": peers,
            "remote_items": len(link.presence.items()),
            "bad_announcements": counters.bad_keys,
            "refused_items": counters.refused_items,
            "unchecked_types": counters.unchecked_types,
            "refused_calls": counters.refused_calls,
            "malformed": counters.malformed,
            "oversized": counters.oversized,
            "sent": {
                t: {
                    "key": st.key,
                    "matched": st.matched,
                    "messages": st.sent,
                    "bytes": st.bytes_sent,
                    "rate_hz": st.meter.rate(now),
                    "dropped": outbox.dropped(st.key) if outbox is not None and st.key else 0,
                    "rate_limited": st.limit.limited if st.limit is not None else 0,
                    "latched": st.latched is not None,
                }
                for t, st in link.sent.items()
            },
            "received": {
                t: {
                    "key": rt.item.data_key,
                    "robot": rt.item.namespace,
                    "subscribed": rt.subscriber is not None,
                    "messages": rt.received,
                    "bytes": rt.bytes_received,
                    "rate_hz": rt.meter.rate(now),
                    "dropped": inbox.dropped(t) if inbox is not None else 0,
                    "refused": rt.refused,
                    "latched": rt.latched_seen,
                }
                for t, rt in link.received.items()
            },
            "services_sent": {
                n: {"key": s.key, "calls": s.calls, "errors": s.errors, "refused": s.refused}
                for n, s in link.sent_services.items()
            },
            "services_received": {
                n: {"key": s.item.data_key, "calls": s.calls, "errors": s.errors, "refused": s.refused}
                for n, s in link.received_services.items()
            },
            "announce_period": ANNOUNCE_PERIOD,
        }
