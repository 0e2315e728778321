"""Services both ways between the ROS 1 master and rmw_zenoh, as rmw_zenoh does services: Zenoh queryables.

**ROS 1 -> ROS 2.** A ROS 1 service matching ``to_ros2`` is probed for its type; the type's request and
response are mapped (``mrosd.ros2.srvtypes``) and a queryable (``complete``) is declared on the service key
``<domain>/<name>/<pkg>::srv::dds_::<X>_/<hash>`` with an ``SS`` token (QoS: rmw's services default, keep last
10). A query (``rmw_client_data.cpp``: the request's CDR, an attachment with sequence number, timestamp and
the client's GID) is decided on Zenoh's thread: its attachment parsed and its CDR converted to ROS 1 first (a
malformed request is an error reply at once and takes no slot), then admitted under the caps of calls in
flight: in all, per service, and per calling peer (the query's source id when it carries one, else the
client's GID; a hostile peer can claim any, so the total and per-service caps are what bound it). It is then
served on the loop: the service called on its own TCPROS connection with a timeout, and the reply's CDR goes
back with the attachment ``rmw_service_data.cpp`` writes (the request's sequence number and GID, a fresh
timestamp). Anything else is an error reply: rmw_zenoh's client then logs it and the call fails, it never
hangs.

**ROS 2 -> ROS 1.** A service server's ``SS`` token (another session's) matching ``from_ros2``, whose type
mrosd knows in its ROS 1 form with the same hash, is advertised on the ROS 1 master; a ROS 1 call becomes a
``get`` on the service key (target ALL_COMPLETE, no consolidation, as rmw_zenoh's querier) from the bridge's
client, which holds an ``SC`` token, with the request's sequence number and the client's GID. The first
reply answers; an error reply, no reply within the timeout, or too many calls in flight are a clear ROS 1
error. When the last server's token goes, the ROS 1 service is withdrawn.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.errors import MasterUnreachableError, MrosError, RemoteProtocolError, ServiceError
from mrosd.fleet.handoff import ReplyFuture
from mrosd.fleet.keys import NameFilter
from mrosd.lograte import RateLimitedLog
from mrosd.names import canonicalize, is_valid_name
from mrosd.ros2.attachment import decode_attachment, encode_attachment, gid_of
from mrosd.ros2.keys import EntityKind, LivelinessToken, Qos, data_key, ros2_type_of_dds
from mrosd.ros2.srvtypes import HUMBLE_TYPE_HASH, ServiceMapping, ros1_service_for, service_mapping

if TYPE_CHECKING:
    from collections.abc import Callable

    from mrosd.ros2.types import TypeMapper
    from mrosd.tcpros.node import Node

__all__ = ["CALL_TIMEOUT", "MAX_CALLS_PER_PEER", "MAX_INFLIGHT_CALLS", "Ros2Services"]

log = logging.getLogger(__name__)
#: a few lines per kind a minute: what peers can trigger is logged under one key per kind, never one per name
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: seconds a call may take in either direction (rmw_zenoh's querier default is 10 s)
CALL_TIMEOUT = 10.0
#: calls in flight at once in each direction; more are refused at once
MAX_INFLIGHT_CALLS = 64
#: of the calls from ROS 2 in flight, from one calling peer (as the fleet part's services)
MAX_CALLS_PER_PEER = 8
#: ROS 2 servers remembered per service provided on ROS 1 (the service stays while one is left)
MAX_SERVERS = 256
#: services bridged in each direction at most
MAX_SERVICES = 256
#: seconds allowed to probe a ROS 1 service for its type
PROBE_TIMEOUT = 3.0
#: a request or response body larger than this is refused before it is converted (services carry commands,
#: not images; rmw_zenoh has no limit of its own)
MAX_SERVICE_BODY = 16 * 1024 * 1024
#: bytes of the requests from ROS 2 in flight (each counted as its CDR body and its ROS 1 form, held until the
#: call ends): a call that would pass it is refused at once, so memory follows this, not a peer's calls
MAX_INFLIGHT_BYTES = 64 * 1024 * 1024
#: rmw's rmw_qos_profile_services_default: reliable, volatile, keep last 10 (the token's QoS)
SERVICE_QOS = Qos(depth=10)


def _caller_of(query: Any, gid: bytes) -> str:
    """Who calls, for the per-peer cap (Zenoh's thread): the query's source session when it says one, else
    the calling client's GID from the attachment (rmw_zenoh's clients set no source info)."""
    with contextlib.suppress(Exception):
        info = query.source_info
        if info is not None and info.source_id is not None:
            return f"zid {info.source_id.zid}"
    return f"gid {gid.hex()}"


@dataclass
class OfferedService:
    """A ROS 1 service shown to ROS 2 as a queryable."""

    name: str
    mapping: ServiceMapping | None = None
    key: str = ""
    md5sum: str = ""
    #: the raw-body service class its calls go through
    raw: Any = None
    queryable: Any = None
    token: Any = None
    calls: int = 0
    errors: int = 0
    refused: int = 0
    problem: str = ""


@dataclass
class ProvidedService:
    """A ROS 2 service provided on the ROS 1 master, served by queries."""

    name: str
    key: str
    mapping: ServiceMapping
    servers: set[str] = field(default_factory=set)
    service: Any = None
    token: Any = None
    gid: bytes = b""
    sequence: int = 0
    calls: int = 0
    errors: int = 0
    refused: int = 0


class Ros2Services:
    """Both directions of services for one ``Ros2Bridge`` (on its loop, but for the query admission)."""

    def __init__(
        self,
        *,
        node: Node,
        mapper: TypeMapper,
        session: Any,
        zenoh: Any,
        domain_id: int,
        humble: bool,
        to_ros2: tuple[str, ...],
        from_ros2: tuple[str, ...],
        make_token: Callable[..., LivelinessToken],
        changed: Callable[[], None],
        call_timeout: float = CALL_TIMEOUT,
        max_calls: int = MAX_INFLIGHT_CALLS,
    ) -> None:
        self.node = node
        self.mapper = mapper
        self.session = session
        self.zenoh = zenoh
        self.domain_id = domain_id
        self.humble = humble
        self.to_filter = NameFilter(include=to_ros2)
        self.from_filter = NameFilter(include=from_ros2)
        self.make_token = make_token
        self.changed = changed
        self.call_timeout = call_timeout
        self.max_calls = max(1, max_calls)
        self.offered: dict[str, OfferedService] = {}
        self.provided: dict[str, ProvidedService] = {}
        #: services being set up -> the liveliness keys of their servers seen meanwhile
        self._providing: dict[str, set[str]] = {}
        #: of ``max_calls``, how many one calling peer and one service may hold
        self.per_peer = max(1, min(MAX_CALLS_PER_PEER, self.max_calls // 4))
        self.per_service = max(1, self.max_calls // 2)
        self._by_peer: Counter[str] = Counter()
        self._by_service: Counter[str] = Counter()
        self.inflight_in = 0
        #: bytes the calls in ``inflight_in`` hold (of ``MAX_INFLIGHT_BYTES``)
        self.inflight_bytes = 0
        self.inflight_out = 0
        self.closed = False
        self._tasks: set[asyncio.Task[None]] = set()
        self._loop = asyncio.get_running_loop()
        #: guards ``inflight_in`` and its counters (raised on Zenoh's threads, lowered on the loop)
        self._lock = threading.Lock()

    def _hash(self, mapping: ServiceMapping) -> str:
        return HUMBLE_TYPE_HASH if self.humble else mapping.type_hash

    def _spawn(self, coro: Any) -> None:
        task = asyncio.create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    @staticmethod
    def _carriable(name: str) -> bool:
        return name.startswith("/") and is_valid_name(name) and canonicalize(name) == name

    # --- ROS 1 -> ROS 2 ------------------------------------------------------------------------------

    async def reconcile(self, srvs: Any) -> None:
        """Offer the ROS 1 services matching ``to_ros2`` provided by another node; withdraw the rest."""
        own = self.node.name
        want = {
            str(name)
            for name, nodes in srvs
            if name in self.to_filter
            and name not in self.provided
            and any(n != own for n in nodes)
            and self._carriable(str(name))
        }
        for name in sorted(want - set(self.offered)):
            if len(self.offered) >= MAX_SERVICES:
                _ratelog.warning("max services", "ros2: more than %d services to offer; the rest are not", MAX_SERVICES)
                break
            await self._offer(name)
        for name in set(self.offered) - want:
            self._withdraw(self.offered.pop(name))
        self.changed()

    async def _offer(self, name: str) -> None:
        from mrosd.msg import get_service_class
        from mrosd.tcpros.service import probe_service

        os_ = self.offered[name] = OfferedService(name)
        try:
            fields = await probe_service(self.node.master, name, self.node.name, PROBE_TIMEOUT)
            srv_type, os_.md5sum = fields["type"], fields.get("md5sum", "")
        except (MrosError, TimeoutError, KeyError) as exc:
            # the server is not reachable yet (or went): tried again at the next read of the graph
            _ratelog.warning(f"probe {name}", "ros2: cannot probe service %s: %s", name, exc)
            self.offered.pop(name, None)
            return
        try:
            cls: Any = await asyncio.to_thread(get_service_class, srv_type)
            if os_.md5sum not in ("", "*") and cls._md5sum != os_.md5sum:
                raise ServiceError(f"its md5 {os_.md5sum} is not that of mrosd's {srv_type} ({cls._md5sum})")
            os_.md5sum = cls._md5sum
            mapping = await asyncio.to_thread(
                service_mapping,
                self.mapper,
                srv_type,
                str(cls._request_class._full_text),
                str(cls._response_class._full_text),
            )
        except (MrosError, TimeoutError, ValueError, KeyError) as exc:
            # kept with its problem until it leaves the graph: one line, no probe per graph read
            os_.problem = f"ros2: service {name} is not offered to ROS 2: {exc}"
            _ratelog.warning(f"offer {name}", "%s", os_.problem)
            return
        if self.closed or self.offered.get(name) is not os_:
            return
        from mrosd.fleet.raw import raw_service_class

        os_.mapping = mapping
        os_.raw = raw_service_class(mapping.ros1_type, os_.md5sum)
        os_.key = data_key(self.domain_id, name, mapping.ros2_type, self._hash(mapping))
        loop = self._loop

        def on_query(query: Any) -> None:  # Zenoh's thread: checked, then admitted or refused, at once
            why = ""
            try:
                payload = query.payload
                size = len(payload) if payload is not None else 0
                if not size or size > MAX_SERVICE_BODY:  # measured before it is copied out of Zenoh
                    why = f"a request of {size} bytes"
                else:  # bounded by the body's size: a malformed request never takes a slot
                    raw = query.attachment
                    attachment = decode_attachment(raw.to_bytes() if raw is not None else b"")
                    request = bytes(self.mapper.to_ros1(mapping.request_type, payload.to_bytes()))
            except (RemoteProtocolError, MrosError) as exc:
                why = str(exc)
            if not why:
                peer = _caller_of(query, attachment.gid)
                held = size + len(request)
                if self._admit(name, peer, held):
                    try:
                        loop.call_soon_threadsafe(
                            self._spawn, self._serve(os_, query, request, attachment, peer, held=held)
                        )
                        return  # handed over: the loop replies and drops it
                    except RuntimeError:  # the loop is gone
                        self._call_done(name, peer, held)
                why = "too many calls in flight"
            os_.refused += 1
            _ratelog.warning("bad query", "ros2: refusing a call of %s: %s", name, why)
            with contextlib.suppress(Exception):
                query.reply_err(f"mrosd: {name}: {why}".encode())
            with contextlib.suppress(Exception):
                query.drop()

        try:
            # on Zenoh's own thread: zenoh-python's default (``indirect``) queues queries for a Python thread
            # with no bound, where a peer's requests would pile up while the GIL is busy
            os_.queryable = self.session.declare_queryable(
                os_.key, self.zenoh.handlers.Callback(on_query, indirect=False), complete=True
            )
            token = self.make_token(EntityKind.SERVICE, name, mapping, qos=SERVICE_QOS, type_hash=self._hash(mapping))
            os_.token = self.session.liveliness().declare_token(token.key())
        except Exception as exc:
            os_.problem = f"ros2: Zenoh refused the service {os_.key}: {exc}"
            log.warning("%s", os_.problem)
            self._withdraw(os_)
            return
        log.info("ros2: service %s (%s) -> %s", name, mapping.ros1_type, os_.key)

    async def _serve(
        self, os_: OfferedService, query: Any, request: bytes, attachment: Any, peer: str, *, held: int
    ) -> None:
        mapping, raw = os_.mapping, os_.raw
        assert mapping is not None
        try:
            os_.calls += 1
            try:
                proxy = self.node.service_proxy(os_.name, raw)  # one connection per call
                response = await proxy.call(raw._request_class(request), timeout=self.call_timeout)
                cdr = bytes(self.mapper.to_cdr(mapping.response_type, response.data))
            except (MrosError, TimeoutError, OSError) as exc:
                os_.errors += 1
                text = str(exc) or f"no answer within {self.call_timeout:.0f} s"
                _ratelog.warning(f"call {os_.name}", "ros2: a ROS 2 call of %s failed: %s", os_.name, text)
                query.reply_err(f"mrosd: {os_.name}: {text}".encode()[:1000])
                return
            reply = encode_attachment(attachment.sequence_number, time.time_ns(), attachment.gid)
            query.reply(os_.key, cdr, attachment=reply)
        except Exception as exc:  # Zenoh refused the reply (the querier is gone): nothing to tell anyone
            _ratelog.warning(f"reply {os_.name}", "ros2: cannot answer a call of %s: %s", os_.name, exc)
        finally:
            self._call_done(os_.name, peer, held)
            with contextlib.suppress(Exception):
                query.drop()

    def _admit(self, service: str, peer: str, held: int) -> bool:
        """Take a slot for a call of ``service`` from ``peer`` holding ``held`` bytes if the caps allow (any
        thread)."""
        with self._lock:
            if (
                self.closed
                or self.inflight_in >= self.max_calls
                or self.inflight_bytes + held > MAX_INFLIGHT_BYTES
                or self._by_service[service] >= self.per_service
                or self._by_peer[peer] >= self.per_peer
            ):
                return False
            self.inflight_in += 1
            self.inflight_bytes += held
            self._by_service[service] += 1
            self._by_peer[peer] += 1
            return True

    def _call_done(self, service: str, peer: str, held: int) -> None:
        with self._lock:
            self.inflight_in -= 1
            self.inflight_bytes -= held
            for counter, name in ((self._by_service, service), (self._by_peer, peer)):
                counter[name] -= 1
                if counter[name] <= 0:
                    del counter[name]

    @staticmethod
    def _withdraw(os_: OfferedService) -> None:
        for entity in (os_.token, os_.queryable):
            if entity is not None:
                with contextlib.suppress(Exception):
                    entity.undeclare()
        os_.token = os_.queryable = None

    # --- ROS 2 -> ROS 1 ------------------------------------------------------------------------------

    async def token(self, tok: LivelinessToken, alive: bool, key: str) -> None:
        """An ``SS`` token of another session appeared or went."""
        name = tok.topic
        ps = self.provided.get(name)
        pending = self._providing.get(name)
        if not alive:
            if pending is not None:
                pending.discard(key)
            if ps is not None:
                ps.servers.discard(key)
                if not ps.servers:
                    del self.provided[name]
                    await self._unprovide(ps)
                    self.changed()
            return
        if ps is not None:
            if len(ps.servers) < MAX_SERVERS:
                ps.servers.add(key)
            return
        if pending is not None:  # being set up (its types load off the loop): one ROS 1 service per name
            if len(pending) < MAX_SERVERS:
                pending.add(key)
            return
        if tok.domain_id != self.domain_id or name not in self.from_filter or name in self.offered:
            return
        if not self._carriable(name):
            _ratelog.warning("svc name", "ros2: service %r from ROS 2 is not a ROS name; not provided", name[:200])
            return
        if len(self.provided) >= MAX_SERVICES:
            _ratelog.warning(
                "max services in",
                "ros2: ROS 2 offers more than %d services; %s is not provided",
                MAX_SERVICES,
                name[:200],
            )
            return
        self._providing[name] = {key}
        try:
            await self._provide(tok)
        finally:
            self._providing.pop(name, None)

    async def _provide(self, tok: LivelinessToken) -> None:
        from mrosd.fleet.raw import RawBody, raw_service_class
        from mrosd.msg import get_service_class

        name = tok.topic
        try:
            ros1_type = ros1_service_for(self.mapper, ros2_type_of_dds(tok.type_name))
            cls: Any = await asyncio.to_thread(get_service_class, ros1_type)
            mapping = await asyncio.to_thread(
                service_mapping,
                self.mapper,
                ros1_type,
                str(cls._request_class._full_text),
                str(cls._response_class._full_text),
            )
        except (MrosError, ValueError) as exc:
            _ratelog.warning("provide", "ros2: service %s from ROS 2 is not provided: %s", name[:200], exc)
            return
        if tok.type_hash != self._hash(mapping):
            _ratelog.warning(
                "svc hash",
                "ros2: service %s: the ROS 2 server's %s hash %s is not ours (%s); not provided",
                name,
                mapping.ros2_type,
                tok.type_hash,
                self._hash(mapping),
            )
            return
        if self.closed or name in self.provided:
            return
        try:  # a ROS 1 node's service of that name is never taken over (the master would let us)
            await self.node.master.lookup_service(name)
        except MasterUnreachableError:
            return  # tried again when the token is announced anew
        except MrosError:
            pass
        else:
            _ratelog.warning("taken", "ros2: %s is a ROS 1 service already; not provided from ROS 2", name)
            return
        servers = self._providing.get(name)
        if not servers:
            return  # every server went while its types were loading
        ps = self.provided[name] = ProvidedService(
            name, data_key(self.domain_id, name, mapping.ros2_type, tok.type_hash), mapping, set(servers)
        )
        raw = raw_service_class(ros1_type, cls._md5sum)

        async def handler(request: RawBody) -> RawBody:
            body = await self._call(ps, request.data)
            response: RawBody = raw._response_class(body)
            return response

        client = self.make_token(EntityKind.CLIENT, name, mapping, qos=SERVICE_QOS, type_hash=tok.type_hash)
        ps.gid = gid_of(client.key())
        try:
            ps.token = self.session.liveliness().declare_token(client.key())
            ps.service = await self.node.advertise_service(name, raw, handler)
        except Exception as exc:
            _ratelog.warning(f"provide {name}", "ros2: cannot provide %s on ROS 1: %s", name, exc)
            if self.provided.get(name) is ps:
                del self.provided[name]
            await self._unprovide(ps)
            return
        if self.provided.get(name) is not ps:  # its last server went while the master registered it
            await self._unprovide(ps)
            return
        log.info("ros2: service %s <- %s (%s)", name, ps.key, ros1_type)
        self.changed()

    async def _call(self, ps: ProvidedService, request: bytes) -> bytes:
        """One ROS 1 call through Zenoh: the ROS 1 response body.

        Raises:
            ServiceError: too many calls, a body that does not convert, an error reply, no reply in time.
        """
        ps.calls += 1
        if self.inflight_out >= self.max_calls or self.closed:
            ps.refused += 1
            raise ServiceError(f"ros2: {ps.name}: too many calls in flight to ROS 2")
        self.inflight_out += 1
        try:
            return await self._query(ps, request)
        except ServiceError:
            ps.errors += 1
            raise
        finally:
            self.inflight_out -= 1

    async def _query(self, ps: ProvidedService, request: bytes) -> bytes:
        zenoh = self.zenoh
        try:
            cdr = bytes(self.mapper.to_cdr(ps.mapping.request_type, request))
        except MrosError as exc:
            raise ServiceError(str(exc)) from None
        outcome = ReplyFuture(asyncio.get_running_loop())
        answered = threading.Event()

        def on_reply(reply: Any) -> None:  # Zenoh's thread
            if answered.is_set():  # the first reply decides: what other queryables send is not even copied
                return
            answered.set()
            if reply.ok is not None:
                size = len(reply.ok.payload)
                if size > MAX_SERVICE_BODY:
                    outcome.fail(f"ros2: {ps.name}: a response of {size} bytes")
                else:
                    outcome.ok(reply.ok.payload.to_bytes())
                return
            text = reply.err.payload.to_bytes()[:500].decode("utf-8", "replace")
            if text == "Timeout":  # Zenoh's own error reply once the query's timeout has passed
                outcome.fail(f"ros2: {ps.name}: no answer from ROS 2 within {self.call_timeout:g} s")
            else:
                outcome.fail(f"ros2: {ps.name}: the ROS 2 server answered an error: {text}")

        def on_done() -> None:
            outcome.fail(f"ros2: {ps.name}: no answer from ROS 2")

        ps.sequence += 1
        attachment = encode_attachment(ps.sequence, time.time_ns(), ps.gid)
        self.session.get(
            ps.key,
            zenoh.handlers.Callback(on_reply, on_done, indirect=False),
            payload=cdr,
            attachment=attachment,
            target=zenoh.QueryTarget.ALL_COMPLETE,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.call_timeout,
        )
        try:
            async with backports.timeout(self.call_timeout + 1.0):
                body = await outcome.future
        except TimeoutError:
            raise ServiceError(f"ros2: {ps.name}: no answer within {self.call_timeout:.0f} s") from None
        try:
            return bytes(self.mapper.to_ros1(ps.mapping.response_type, body))
        except MrosError as exc:
            raise ServiceError(str(exc)) from None

    async def _unprovide(self, ps: ProvidedService) -> None:
        if ps.token is not None:
            with contextlib.suppress(Exception):
                ps.token.undeclare()
        if ps.service is not None:
            with contextlib.suppress(MrosError, OSError):
                await ps.service.aclose()

    # --- status and lifecycle ------------------------------------------------------------------------

    def status(self) -> list[dict[str, Any]]:
        """One row per bridged service, each direction."""
        rows: list[dict[str, Any]] = [
            {
                "service": o.name,
                "direction": "to_ros2",
                "ros2_type": o.mapping.ros2_type if o.mapping else "",
                "key": o.key,
                "calls": o.calls,
                "errors": o.errors,
                "refused": o.refused,
                "problem": o.problem,
            }
            for o in self.offered.values()
        ]
        rows += [
            {
                "service": p.name,
                "direction": "from_ros2",
                "ros2_type": p.mapping.ros2_type,
                "key": p.key,
                "calls": p.calls,
                "errors": p.errors,
                "refused": p.refused,
                "problem": "",
            }
            for p in self.provided.values()
        ]
        return rows

    async def aclose(self) -> None:
        self.closed = True
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for os_ in self.offered.values():
            self._withdraw(os_)
        self.offered.clear()
        for ps in list(self.provided.values()):
            await self._unprovide(ps)
        self.provided.clear()
