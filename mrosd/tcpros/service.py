"""Services: the server side (``Service``) and the client side (``ServiceProxy``), rospy-compatible.

A request is one frame; a response is an ok byte (1 = success, 0 = failure) followed by one frame holding
either the serialized response or, on failure, the UTF-8 error text, as rospy and roscpp send it. Probe
connections (``probe=1``, used by ``rosservice``) get the header and are closed. Non-persistent client
connections are closed after one response; persistent ones are kept for further calls.
"""

from __future__ import annotations

import asyncio
import collections
import inspect
import logging
from typing import TYPE_CHECKING, Any, NamedTuple

from mrosd import backports
from mrosd.errors import (
    HandshakeError,
    LocalProtocolError,
    MasterError,
    MrosError,
    RemoteProtocolError,
    ServiceError,
)
from mrosd.lograte import RateLimitedLog
from mrosd.spin import loop_spinner
from mrosd.tcpros.protocol import TcprosProtocol
from mrosd.tcpros.sockopts import enable_keepalive
from mrosd.wire.framing import MAX_FRAME_SIZE, FrameDecoder, Response, encode_frame
from mrosd.wire.handshake import check_service_reply, error_header, service_reply
from mrosd.wire.header import MAX_HEADER_SIZE, ConnectionHeader, decode_connection_header, encode_header

if TYPE_CHECKING:
    from collections.abc import Callable

    from mrosd.master.client import MasterClient
    from mrosd.tcpros.owner import EndpointOwner

log = logging.getLogger(__name__)
#: what peers get wrong (a refused handshake, a request the handler raises on): a few lines per service and
#: minute, never one per call
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: Requests a persistent client may pipeline before we stop reading from it (the bound of its queue).
MAX_PENDING_REQUESTS = 64
#: Time allowed for connecting and the handshake, and the default for a whole call.
CONNECT_TIMEOUT = 10.0
#: Bytes asked of the stream per read while a response is incomplete.
_READ_SIZE = 256 * 1024


def _srv_attrs(srv_class: Any) -> tuple[str, str, Any, Any]:
    for attr in ("_type", "_md5sum", "_request_class", "_response_class"):
        if not hasattr(srv_class, attr):
            raise LocalProtocolError(
                f"{srv_class!r} is not a service class (no {attr}); use mrosd.msg.get_service_class"
            )
    return srv_class._type, srv_class._md5sum, srv_class._request_class, srv_class._response_class


class ServiceProtocol(TcprosProtocol):
    """Inbound connection after its header asked for one of our services."""

    service: Service | None = None
    persistent = False

    def start(self, service: Service, persistent: bool) -> None:
        self.service = service
        self.persistent = persistent
        self.pending: collections.deque[bytes | bytearray] = collections.deque()
        self.wake = asyncio.Event()
        self.task = asyncio.get_running_loop().create_task(self._serve())

    def frame_received(self, body: bytes | bytearray) -> None:
        if self.service is None:
            return
        if len(self.pending) >= MAX_PENDING_REQUESTS:
            self.abort(
                f"service {self.service.name}: client {self.peer} pipelined over {MAX_PENDING_REQUESTS} requests"
            )
            return
        self.pending.append(body)
        self.wake.set()

    def connection_closed(self, exc: BaseException | None) -> None:
        if self.service is not None:
            self.wake.set()

    async def _serve(self) -> None:
        service = self.service
        assert service is not None
        while self.transport is not None:
            if not self.pending:
                self.wake.clear()
                await self.wake.wait()
                continue
            body = self.pending.popleft()
            ok, payload = await service._handle(body)
            if self.transport is None:
                return
            self.transport.write(encode_frame(payload, ok=ok))
            if not self.persistent:
                self.close()
                return


class Service:
    """A service we provide. Create it with ``await node.advertise_service(name, SrvType, handler)``."""

    def __init__(self, node: EndpointOwner, name: str, srv_class: Any, handler: Callable[[Any], Any]) -> None:
        self.type, self.md5sum, self.request_class, self.response_class = _srv_attrs(srv_class)
        self.node = node
        self.name = name
        self.handler = handler
        self.calls = 0
        self.closed = False
        self.connections: set[ServiceProtocol] = set()

    def accept(self, proto: ServiceProtocol, header: ConnectionHeader) -> None:
        """Handshake with a service client (called by the node's TCPROS server)."""
        try:
            reply = service_reply(
                header,
                service=self.name,
                srv_type=self.type,
                md5sum=self.md5sum,
                request_type=self.request_class._type,
                response_type=self.response_class._type,
                callerid=self.node.name,
            )
        except HandshakeError as exc:
            _ratelog.warning(
                self.name + ":refused", "service %s: refusing client %s: %s", self.name, header.callerid, exc
            )
            proto.write(encode_header(error_header(str(exc))))
            proto.close()
            return
        proto.write(encode_header(reply))
        if header.flag("probe"):
            proto.close()
            return
        proto.start(self, header.flag("persistent"))
        self.connections.add(proto)
        proto.closed.add_done_callback(lambda _f: self.connections.discard(proto))

    async def _handle(self, body: bytes | bytearray) -> tuple[bool, bytes]:
        self.calls += 1
        try:
            request = self.request_class.deserialize(body)
        except MrosError as exc:
            return False, f"cannot decode the request: {exc}".encode()
        try:
            response = self.handler(request)
            if inspect.isawaitable(response):
                response = await response
            if response is None:
                return False, f"service handler for {self.name} returned None".encode()
            if not isinstance(response, self.response_class):
                if isinstance(response, dict):
                    response = self.response_class(**response)
                else:
                    return (
                        False,
                        f"service handler returned {type(response).__name__}, not {self.response_class._type}".encode(),
                    )
            return True, response.serialize()
        except Exception as exc:
            _ratelog.warning(self.name + ":raised", "service %s: handler raised %r", self.name, exc)
            return False, f"error processing request: {exc}".encode()

    async def aclose(self) -> None:
        """Unregister from the master and close client connections."""
        if self.closed:
            return
        self.closed = True
        for proto in list(self.connections):
            proto.close()
        await self.node.endpoint_closed(self)

    async def __aenter__(self) -> Service:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()


class ServiceProxy:
    """Calls a service: ``resp = await proxy.call(req)`` or ``await proxy(req)``; persistent keeps one connection."""

    def __init__(self, node: EndpointOwner, name: str, srv_class: Any, *, persistent: bool = False) -> None:
        self.type, self.md5sum, self.request_class, self.response_class = _srv_attrs(srv_class)
        self.node = node
        self.name = name
        self.persistent = persistent
        self._conn: _Connection | None = None
        self._lock = asyncio.Lock()

    async def _lookup(self) -> tuple[str, int]:
        uri = await self.node.master.lookup_service(self.name)
        if not uri.startswith("rosrpc://"):
            raise ServiceError(f"service {self.name}: master returned an unusable URI {uri!r}")
        hostport = uri[len("rosrpc://") :].rstrip("/")
        host, _, port = hostport.rpartition(":")
        return host.strip("[]"), int(port)

    async def _connect(self) -> _Connection:
        host, port = await self._lookup()
        reader, writer = await asyncio.open_connection(host, port, limit=2**20)
        conn = _Connection.over(reader, writer)
        try:
            sock = writer.get_extra_info("socket")
            if sock is not None:
                enable_keepalive(sock)
            header = ConnectionHeader(
                callerid=self.node.name,
                service=self.name,
                md5sum=self.md5sum,
                persistent="1" if self.persistent else "0",
            )
            writer.write(encode_header(header))
            _, raw = await conn.receive()
            check_service_reply(decode_connection_header(raw), service=self.name, md5sum=self.md5sum)
        except BaseException:
            writer.close()
            raise
        return conn

    async def wait_for_service(self, timeout: float = 10.0) -> None:
        """Wait until the master knows the service.

        Raises:
            TimeoutError: it did not appear in time.
        """
        async with backports.timeout(timeout):
            while True:
                try:
                    await self._lookup()
                    return
                except MrosError:
                    await asyncio.sleep(0.1)

    async def call(self, request: Any, timeout: float = CONNECT_TIMEOUT) -> Any:
        """Send one request and return the response.

        Raises:
            ServiceError: the server answered with an error string, or the service is unknown or unreachable.
            HandshakeError: the server refused the connection (e.g. md5 mismatch).
            TimeoutError: no answer within ``timeout`` seconds.
        """
        if not isinstance(request, self.request_class):
            raise LocalProtocolError(f"{self.name} takes {self.request_class._type}, got {type(request).__name__}")
        body = request.serialize()
        async with self._lock, backports.timeout(timeout):
            conn = self._conn
            try:
                if conn is None:
                    conn = await self._connect()
                conn.writer.write(encode_frame(body))
                loop_spinner().poke()  # the answer is near: keep the loop polling for it
                ok, payload = await conn.receive()
            except HandshakeError:
                self._drop(conn)
                raise
            except (OSError, RemoteProtocolError) as exc:
                self._drop(conn)
                raise ServiceError(f"service {self.name}: connection failed: {exc}") from exc
            except MasterError as exc:
                self._drop(conn)
                raise ServiceError(f"service [{self.name}] unavailable: {exc}") from exc
            except BaseException:
                self._drop(conn)
                raise
            if self.persistent:
                self._conn = conn
            else:
                self._drop(conn)
        if not ok:
            raise ServiceError(f"service [{self.name}] responded with an error: {payload.decode(errors='replace')}")
        return self.response_class.deserialize(payload)

    __call__ = call

    def _drop(self, conn: _Connection | None) -> None:
        if conn is not None:
            conn.writer.close()
        if conn is self._conn:
            self._conn = None

    async def aclose(self) -> None:
        """Close a persistent connection."""
        conn, self._conn = self._conn, None
        if conn is not None:
            conn.writer.close()
            try:
                await conn.writer.wait_closed()
            except OSError:
                pass

    async def __aenter__(self) -> ServiceProxy:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()


class _Connection(NamedTuple):
    """A client's connection to a service: the stream, and the decoder of the server's header and responses."""

    reader: asyncio.StreamReader
    writer: asyncio.StreamWriter
    decoder: FrameDecoder

    @classmethod
    def over(cls, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> _Connection:
        return cls(reader, writer, FrameDecoder(MAX_FRAME_SIZE, header_max_size=MAX_HEADER_SIZE, ok_byte=True))

    async def receive(self) -> Response:
        """The server's next frame: its connection header first, then one (ok, body) per request.

        Raises:
            RemoteProtocolError: the server closed the connection, announced a frame over the limit, or sent
                more than was asked for (a response nobody requested would answer the next call).
        """
        while True:
            data = await self.reader.read(_READ_SIZE)
            if not data:
                raise RemoteProtocolError("the server closed the connection before answering")
            got = self.decoder.feed_responses(data)
            if got:
                if len(got) > 1 or self.decoder.buffered:
                    raise RemoteProtocolError("the server sent more than one answer to one request")
                return got[0]


#: Seconds a probe of a service's server may take (connect, send the header, read the answer).
PROBE_TIMEOUT = 5.0


async def probe_service(
    master: MasterClient, service: str, callerid: str, timeout: float = PROBE_TIMEOUT
) -> dict[str, str]:
    """The header a service's server answers to a ``probe=1`` connection, as rosservice asks for a type:
    ``type``, ``md5sum``, ``request_type``, ``response_type``. Shared by ``mros service`` and the fleet part.

    Raises:
        MasterError: the service is not registered.
        ServiceError: the master's URI is unusable, the server cannot be reached, answers an error or no type.
    """
    import struct
    import urllib.parse

    from mrosd.wire.header import decode_header

    uri: str = await master.lookup_service(service)
    parsed = urllib.parse.urlsplit(uri)
    if parsed.scheme != "rosrpc" or not parsed.hostname or parsed.port is None:
        raise ServiceError(f"service {service}: the master gave an unusable URI {uri!r}")
    header = encode_header({"callerid": callerid, "service": service, "md5sum": "*", "probe": "1"})
    try:
        async with backports.timeout(timeout):
            reader, writer = await asyncio.open_connection(parsed.hostname, parsed.port)
            try:
                writer.write(header)
                (size,) = struct.unpack("<I", await reader.readexactly(4))
                if size > MAX_HEADER_SIZE:
                    raise ServiceError(f"service {service}: header of {size} bytes is too big")
                fields = decode_header(await reader.readexactly(size))
            finally:
                writer.close()
    except (OSError, TimeoutError, asyncio.IncompleteReadError) as exc:
        raise ServiceError(f"service {service}: cannot probe {uri}: {exc or type(exc).__name__}") from exc
    if "error" in fields:
        raise ServiceError(f"service {service}: {fields['error']}")
    if not fields.get("type"):
        raise ServiceError(f"service {service}: the server did not say its type")
    return fields
