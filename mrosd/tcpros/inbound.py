"""A node's inbound TCPROS connections: admitted by its listener, then routed by header to a publisher or service.

Owns the connections the node accepted and that are still open (``InboundConnections``: the node must close
them itself, asyncio's ``Server.close()`` does not) and the routing of each by its connection header
(``InboundProtocol``), with the rate-limited refusal a peer can provoke at will. Must not know the node
itself: it reads the node's name, endpoints and closing flag through ``InboundOwner``, so ``mrosd.tcpros.node``
imports this module and never the other way round.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping
from typing import Protocol

from mrosd.lograte import RateLimitedLog
from mrosd.tcpros.admission import AdmissionLimits
from mrosd.tcpros.listener import AdmittedConnection, TcprosListener
from mrosd.tcpros.publisher import Publisher, PublisherProtocol
from mrosd.tcpros.service import Service, ServiceProtocol
from mrosd.tcpros.sockopts import enable_keepalive
from mrosd.wire.framing import MAX_FRAME_SIZE, FrameDecoder
from mrosd.wire.handshake import error_header
from mrosd.wire.header import ConnectionHeader, encode_header

log = logging.getLogger(__name__)
#: Refusals a peer can provoke at will (a wrong topic, a bad header): reported, not echoed per connection.
refusals = RateLimitedLog(log, period=10.0, burst=5)


class InboundOwner(Protocol):
    """What an inbound connection reads from its node."""

    name: str
    #: set once the node began closing: late connections to closed endpoints are then expected
    closing: bool

    @property
    def publishers(self) -> Mapping[str, Publisher]: ...

    @property
    def services(self) -> Mapping[str, Service]: ...


class InboundConnections:
    """The node's listener and every connection it accepted that is still open."""

    def __init__(self, owner: InboundOwner, limits: AdmissionLimits) -> None:
        self.owner = owner
        self.limits = limits
        self.listener: TcprosListener | None = None
        self.open: set[InboundProtocol] = set()

    def __len__(self) -> int:
        return len(self.open)

    def start(self, host: str, backlog: int = 1024) -> int:
        """Listen on ``host`` (port 0); the bound port."""
        self.listener = TcprosListener(lambda: InboundProtocol(self), self.limits, self.owner.name)
        return self.listener.start(host, 0, backlog=backlog)

    async def aclose(self) -> None:
        """Stop listening, then abort every connection still open but those flushing their last frames."""
        if self.listener is not None:
            await self.listener.aclose()  # the connections it accepted last join ``open`` first
            self.listener = None
        if self.open:
            for proto in list(self.open):
                transport = proto.transport
                # those the publishers and services closed are flushing their last frames: leave them be
                if transport is not None and not transport.is_closing():
                    transport.abort()
            self.open.clear()
            await asyncio.sleep(0)  # let the aborted transports finish before the loop may stop


class InboundProtocol(ServiceProtocol, PublisherProtocol, AdmittedConnection):
    """A connection accepted by the node's TCPROS server, routed by its header to a publisher or service.

    Until its header is complete it is only a candidate: the node's listener (``TcprosListener``) may shed
    it (too many waiting, over the header byte budget, past the header deadline, out of descriptors), and
    it reports how many header bytes it holds so that memory follows what peers send.
    """

    def __init__(self, connections: InboundConnections) -> None:
        super().__init__()
        self.connections = connections
        self.node = connections.owner
        self.decoder = FrameDecoder(MAX_FRAME_SIZE, header_max_size=connections.limits.max_header_size)
        self._shed_reason = ""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        # Tracked until it ends, whatever becomes of it: a peer that never sends a header (or one accepted
        # while the node closes) belongs to no publisher or service, and the node must still close it.
        self.connections.open.add(self)
        if self._shed_reason:  # shed between accept and now
            self.transport.abort()  # type: ignore[union-attr]
            return
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                enable_keepalive(sock)
            except OSError as exc:
                log.debug("%s: no TCP keepalive on %s: %s", self.node.name, self.peer, exc)

    def shed(self, reason: str) -> None:
        """The listener drops this connection (it still owes its header): close it without a word."""
        self._shed_reason = reason
        if self.transport is not None:
            self.transport.abort()

    def buffer_updated(self, nbytes: int) -> None:
        super().buffer_updated(nbytes)
        if self.header is None and self.transport is not None and not self.transport.is_closing():
            listener = self.connections.listener
            if listener is not None:
                listener.header_bytes(self, self.decoder.buffered)

    def _refuse(self, reason: str) -> None:
        # While the node closes, a peer that connected to an endpoint just closed (rosout dialling a
        # short-lived node's /rosout) is expected: it gets the error header, the user no warning.
        if self.node.closing:
            log.debug("%s: refusing TCPROS connection from %s: %s", self.node.name, self.peer, reason)
        else:
            refusals.warning("refuse", "%s: refusing TCPROS connection from %s: %s", self.node.name, self.peer, reason)
        self.write(encode_header(error_header(reason)))
        self.close()

    def header_received(self, header: ConnectionHeader) -> None:
        if self.connections.listener is not None:
            self.connections.listener.header_done(self)
        if header.service is not None:
            service = self.node.services.get(header.service)
            if service is None:
                self._refuse(f"no service [{header.service}] on node [{self.node.name}]")
            else:
                service.accept(self, header)
        elif header.topic is not None:
            pub = self.node.publishers.get(header.topic)
            if pub is None:
                self._refuse(f"no topic with name [{header.topic}] on node [{self.node.name}]")
            else:
                pub.accept(self, header)
        else:
            self._refuse("connection header has neither 'topic' nor 'service'")

    def connection_closed(self, exc: BaseException | None) -> None:
        self.connections.open.discard(self)
        if self.connections.listener is not None:
            self.connections.listener.closed(self)
        ServiceProtocol.connection_closed(self, exc)
        PublisherProtocol.connection_closed(self, exc)
