"""Services across the fleet: local ones offered as Zenoh queryables, remote ones provided here.

A local service in ``send_services`` is a queryable on its data key (announced ``srv``). Each request from
Zenoh is checked against the service's request type first (``mrosd.fleet.check``): a malformed one gets an
error reply at once (rospy never answers one, and it would hold a call slot for the whole timeout). The rest
are called each on its own TCPROS connection with a timeout, so slow calls never queue others behind them.
Calls in flight are capped in all and per calling peer: the query's source id when it carries one (mrosd's
own queries do; a hostile peer may claim any, so the total cap is what bounds it), and callers that carry
none share one cap.

A remote service in ``receive_services`` becomes a local service that queries it; its response is checked
against the response type before the local caller gets it.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import Counter
from typing import Any

from mrosd import backports
from mrosd.errors import MrosError, ServiceError
from mrosd.fleet.handoff import ReplyFuture
from mrosd.fleet.keys import Item, ItemKind, data_key, discovery_key
from mrosd.fleet.limits import MAX_BODY_BYTES, MAX_CALL_BYTES
from mrosd.fleet.link import QUERY_TIMEOUT, FleetLink, ReceivedService, SentService, ratelog
from mrosd.fleet.raw import FleetTypeError, RawBody, checker, raw_service_class, service_class
from mrosd.tcpros.service import probe_service

#: Service calls from the fleet in flight at once; more are refused at once.
MAX_INFLIGHT_CALLS = 64
#: Of those, from one calling peer.
MAX_CALLS_PER_PEER = 8
#: Seconds allowed to probe a local service for its type.
PROBE_TIMEOUT = 3.0
#: The peer name of queries that carry no source id.
ANONYMOUS = "anonymous"


def _peer_of(query: Any) -> str:
    """The calling session's id when the query says it (Zenoh's thread); else ``ANONYMOUS``."""
    with contextlib.suppress(Exception):
        info = query.source_info
        if info is not None:
            return str(info.source_id.zid)
    return ANONYMOUS


class Services:
    """The sent and received services of one ``FleetLink``."""

    def __init__(self, link: FleetLink, max_calls: int = MAX_INFLIGHT_CALLS) -> None:
        self.link = link
        self.max_calls = max(1, max_calls)
        self.per_peer = max(1, min(MAX_CALLS_PER_PEER, self.max_calls // 2))
        self._by_peer: Counter[str] = Counter()
        #: the sequence number of our own queries' source info
        self._sn = 0

    # --- offered to the fleet --------------------------------------------------------------------

    async def reconcile(self, srvs: Any) -> None:
        """Offer the local services in ``send_services`` provided by a node other than us; forget the rest."""
        link = self.link
        own = link.node.name
        services = {
            str(name)
            for name, nodes in srvs
            if name in link.options.send_services
            and name not in link.received_services
            and any(n != own for n in nodes)
        }
        for name in services - set(link.sent_services):
            await self._add_sent(name)
        for name in set(link.sent_services) - services:
            link.undeclare(link.sent_services.pop(name).queryable)

    async def _add_sent(self, name: str) -> None:
        link = self.link
        ss = SentService(name)
        link.sent_services[name] = ss
        try:
            fields = await probe_service(link.node.master, name, link.node.name, PROBE_TIMEOUT)
            srv_type, md5sum = fields["type"], fields.get("md5sum", "")
            if not md5sum or md5sum == "*":
                raise ServiceError(f"service {name}: the server did not say its md5sum")
            key = data_key(srv_type, md5sum, link.options.robot, name)
        except (MrosError, ValueError) as exc:
            ratelog.warning(f"probe {name}", "fleet: cannot offer %s: %s", name, exc)
            link.sent_services.pop(name, None)  # tried again at the next look at the graph
            return
        try:
            srv = await service_class(srv_type, md5sum)
            check_request = (await checker(srv._request_class)).check
        except FleetTypeError as exc:
            # Kept, unoffered, until the service leaves the graph: its requests could not be checked.
            link.counters.unchecked_types += 1
            ratelog.warning(f"probe {name}", "fleet: not offering %s: %s", name, exc)
            return
        if link.sent_services.get(name) is not ss or link.closed:
            return
        ss.key = key
        raw = raw_service_class(srv_type, md5sum)
        loop = asyncio.get_running_loop()

        def on_query(query: Any) -> None:
            # Zenoh's thread: a malformed request is refused before it takes a slot (decoding is bounded by the
            # body's size); beyond the caps, or once closing, the call is refused at once; else to the loop.
            payload = query.payload
            size = len(payload) if payload is not None else 0
            if size > MAX_BODY_BYTES:  # refused before it is copied out of Zenoh
                ss.refused += 1
                link.oversized(name, size)
                with query:
                    query.reply_err(b"mrosd fleet: request too big")
                return
            body = payload.to_bytes() if payload is not None else b""
            why = check_request(body)
            if why is not None:
                ss.refused += 1
                link.malformed("request", name, why)
                with query:
                    query.reply_err(f"mrosd fleet: malformed {srv_type} request: {why}".encode())
                return
            peer = _peer_of(query)
            with link.lock:
                counters = link.counters
                admitted = (
                    not link.closed
                    and counters.inflight < self.max_calls
                    and self._by_peer[peer] < self.per_peer
                    and counters.inflight_bytes + size <= MAX_CALL_BYTES
                )
                if admitted:
                    counters.inflight += 1
                    counters.inflight_bytes += size
                    self._by_peer[peer] += 1
                else:
                    link.counters.refused_calls += 1
            if not admitted:
                with query:
                    query.reply_err(b"mrosd fleet: too many calls in flight")
                return
            try:
                loop.call_soon_threadsafe(link.spawn, self._serve_call(ss, raw, query, body, peer))
            except RuntimeError:  # the loop is gone
                self._call_done(peer, size)
                query.drop()

        # On Zenoh's own thread (``indirect=False``): zenoh-python's default queues queries for a Python thread
        # with no bound; ``on_query`` is cheap (a bounded check of the body, then a hand-off or a refusal).
        ss.queryable = link.session.declare_queryable(
            key, link.zenoh.handlers.Callback(on_query, indirect=False), allowed_origin=link.zenoh.Locality.REMOTE
        )
        ss.announced = discovery_key(ItemKind.SERVICE, srv_type, md5sum, link.options.robot, name)
        link.announce()

    async def _serve_call(self, ss: SentService, raw: Any, query: Any, body: bytes, peer: str) -> None:
        link = self.link
        try:
            if link.closed:
                query.reply_err(b"mrosd fleet: closing")
                return
            ss.calls += 1
            # One connection per call: a slow call never queues another behind it.
            proxy = link.node.service_proxy(ss.name, raw)
            try:
                response = await proxy.call(raw._request_class(body), timeout=QUERY_TIMEOUT)
            except (MrosError, TimeoutError, OSError) as exc:
                # The caller learns the error as an error reply (a bridge's ROS client then fails the call).
                ss.errors += 1
                query.reply_err((str(exc) or type(exc).__name__).encode())
                return
            query.reply(ss.key, response.data)
        except Exception as exc:
            ratelog.warning(f"call {ss.name}", "fleet: answering a call of %s failed: %s", ss.name, exc)
        finally:
            self._call_done(peer, len(body))
            with contextlib.suppress(Exception):
                query.drop()

    def _call_done(self, peer: str, size: int) -> None:
        with self.link.lock:
            self.link.counters.inflight -= 1
            self.link.counters.inflight_bytes -= size
            self._by_peer[peer] -= 1
            if self._by_peer[peer] <= 0:
                del self._by_peer[peer]

    # --- provided here -----------------------------------------------------------------------------

    def offer(self, item: Item, local: str) -> bool:
        """A remote service announced under ``local`` (allowed by ``receive_services``): provide it here."""
        link = self.link
        if local in link.received_services or local in link.sent_services:
            return False
        rs = link.received_services[local] = ReceivedService(local, item)
        link.spawn(self._add_received(rs))
        return True

    async def _add_received(self, rs: ReceivedService) -> None:
        link = self.link
        try:
            srv = await service_class(rs.item.type, rs.item.md5sum)
            check_response = (await checker(srv._response_class)).check
        except FleetTypeError as exc:
            link.counters.unchecked_types += 1
            ratelog.warning("unchecked", "fleet: not providing %s: %s", rs.local, exc)
            return  # kept, unprovided, until its announcements stop
        if link.received_services.get(rs.local) is not rs or link.closed:
            return
        raw = raw_service_class(rs.item.type, rs.item.md5sum)
        key = rs.item.data_key

        async def handler(request: RawBody) -> RawBody:
            rs.calls += 1
            try:
                body = await self._query(key, request.data)
            except ServiceError:
                rs.errors += 1
                raise
            why = check_response(body)
            if why is not None:
                rs.errors += 1
                rs.refused += 1
                link.malformed("response", rs.local, why)
                raise ServiceError(f"the remote service sent a malformed {srv._type} response")
            response: RawBody = raw._response_class(body)
            return response

        try:
            rs.service = await link.node.advertise_service(rs.local, raw, handler)
            link.touch()
        except MrosError as exc:
            ratelog.warning(f"srv {rs.local}", "fleet: cannot provide %s here: %s", rs.local, exc)
            link.received_services.pop(rs.local, None)

    async def _query(self, key: str, body: bytes) -> bytes:
        """The first reply to a query on ``key`` (a remote service's response body).

        Raises:
            ServiceError: an error reply, no reply within QUERY_TIMEOUT, or nobody answering.
        """
        link = self.link
        zenoh = link.zenoh
        outcome = ReplyFuture(asyncio.get_running_loop())

        first = [True]

        def on_reply(reply: Any) -> None:  # Zenoh's thread
            if not first[0]:
                return  # only the first reply is read: further ones (from any peer serving the key) cost nothing
            first[0] = False
            if reply.ok is not None:
                size = len(reply.ok.payload)
                if size > MAX_BODY_BYTES:  # refused before it is copied out of Zenoh
                    link.oversized(key, size)
                    outcome.fail(f"the remote service's answer has {size} bytes (at most {MAX_BODY_BYTES})")
                else:
                    outcome.ok(reply.ok.payload.to_bytes())
            else:
                text = reply.err.payload.to_bytes()[:500].decode("utf-8", "replace")
                outcome.fail(f"the remote service answered an error: {text}")

        def on_done() -> None:
            outcome.fail(f"no answer from {key} across the fleet")

        self._sn += 1
        link.session.get(
            key,
            zenoh.handlers.Callback(on_reply, on_done, indirect=False),
            payload=body,
            source_info=zenoh.SourceInfo(link.session.id, self._sn),  # the callee's per-caller cap counts us
            timeout=QUERY_TIMEOUT,
            allowed_destination=zenoh.Locality.REMOTE,
        )
        try:
            async with backports.timeout(QUERY_TIMEOUT + 1.0):
                return await outcome.future
        except TimeoutError:
            raise ServiceError(f"no answer from {key} within {QUERY_TIMEOUT:.0f} s") from None

    async def expire(self, item: Item, local: str) -> None:
        """``item`` went silent: stop providing it here."""
        rs = self.link.received_services.get(local)
        if rs is not None and rs.item == item:
            del self.link.received_services[local]
            await self._close(rs)

    @staticmethod
    async def _close(rs: ReceivedService) -> None:
        if rs.service is not None:
            with contextlib.suppress(MrosError, OSError):
                await rs.service.aclose()

    async def aclose(self) -> None:
        for ss in list(self.link.sent_services.values()):
            self.link.undeclare(ss.queryable)
        for rs in list(self.link.received_services.values()):
            await self._close(rs)
