"""Node: a ROS 1 node living in the caller's event loop.

The node owns its identity (resolved name, remappings), the master connection (thin typed calls over the
shared XML-RPC client), the slave API server, its inbound TCPROS connections (``mrosd.tcpros.inbound``:
the listener that serves publishers and services), and the watchdog that notices a restarted master and
registers everything again. It never owns the loop: ``async with Node(...)`` starts it and ``aclose()``
unregisters and closes everything it opened. It must not know the wire: its endpoints and connections do.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import os
import socket
import sys
import weakref
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from mrosd.errors import LocalProtocolError, MasterError, MasterUnreachableError, MrosError
from mrosd.master.client import MasterClient
from mrosd.msg import get_message_class
from mrosd.names import NodeNames, parse_argv
from mrosd.tcpros.admission import AdmissionLimits
from mrosd.tcpros.inbound import InboundConnections
from mrosd.tcpros.publisher import DEFAULT_QUEUE_SIZE, Publisher
from mrosd.tcpros.rosout import QUEUE_SIZE as ROSOUT_QUEUE_SIZE
from mrosd.tcpros.rosout import ROSOUT_LOGGER, RosoutHandler, logger_service_handlers, node_logger
from mrosd.tcpros.service import Service, ServiceProxy
from mrosd.tcpros.slave import SlaveApi
from mrosd.tcpros.subscriber import Subscriber
from mrosd.xmlrpc import XmlRpcClient, XmlRpcServer

log = logging.getLogger(__name__)

DEFAULT_MASTER_URI = "http://localhost:11311/"
ROSOUT_TOPIC = "/rosout"
#: How often the watchdog asks the master whether it still knows us (lookupNode, one cheap call).
WATCHDOG_INTERVAL = 1.0
#: Upper bound of the watchdog's backoff while the master is unreachable.
WATCHDOG_MAX_INTERVAL = 5.0
#: Timeout of registration calls, and the shorter one for unregistering on exit.
MASTER_TIMEOUT = 10.0
UNREGISTER_TIMEOUT = 2.0


#: Nodes started and not yet closed, so that ``mrosd.run`` can close what an application left open.
_open_nodes: weakref.WeakSet[Node] = weakref.WeakSet()


def open_nodes() -> list[Node]:
    """The nodes of this process that are started and not closed."""
    return list(_open_nodes)


def _is_ipv6(host: str) -> bool:
    try:
        return isinstance(ipaddress.ip_address(host.strip("[]")), ipaddress.IPv6Address)
    except ValueError:
        return False


def _default_host() -> str:
    name = socket.gethostname()
    try:
        socket.getaddrinfo(name, None)
    except OSError:
        return "127.0.0.1"
    return name


class Node:
    """A ROS node: ``async with Node("talker") as node: pub = await node.advertise(...)``.

    Args:
        name: base node name; ``__name:=`` in ``argv`` overrides it, ``__ns:=``/ROS_NAMESPACE place it.
        master_uri: the master; default ``__master:=``, then ROS_MASTER_URI, then http://localhost:11311/.
        argv: command-line arguments with remappings (``from:=to``); default ``sys.argv[1:]``.
        host: the address advertised to peers; default ``__hostname:=``/``__ip:=``, ROS_HOSTNAME, ROS_IP,
            then this machine's hostname. It is advertised exactly as given (IPv6 literals too).
        environ: the environment to read instead of ``os.environ``.
        watchdog_interval: seconds between the checks that the master still knows this node (0 disables).
        rosout: publish the ``rosout`` logger's records (``node.log`` included) on /rosout, as rospy does.
        logger_services: offer ``~get_loggers`` and ``~set_logger_level``, as rospy and roscpp nodes do.
        admission: caps on inbound TCPROS connections and the header deadline (docs/tcpros.md, "Admission").
    """

    def __init__(
        self,
        name: str,
        master_uri: str | None = None,
        argv: Sequence[str] | None = None,
        *,
        host: str | None = None,
        environ: Mapping[str, str] | None = None,
        watchdog_interval: float = WATCHDOG_INTERVAL,
        rosout: bool = True,
        logger_services: bool = True,
        admission: AdmissionLimits | None = None,
    ) -> None:
        env = os.environ if environ is None else environ
        args = list(sys.argv[1:] if argv is None else argv)
        special, _, _ = parse_argv(args)
        self.names = NodeNames.from_argv(name, args, env)
        self.name = self.names.name
        self.master_uri = master_uri or special.get("__master") or env.get("ROS_MASTER_URI") or DEFAULT_MASTER_URI
        self.host = (
            host
            or special.get("__hostname")
            or special.get("__ip")
            or env.get("ROS_HOSTNAME")
            or env.get("ROS_IP")
            or _default_host()
        ).strip("[]")
        self.watchdog_interval = watchdog_interval
        self.publishers: dict[str, Publisher] = {}
        self.subscribers: dict[str, Subscriber] = {}
        self.services: dict[str, Service] = {}
        #: Called as ``cb(key, value)`` for every update of a parameter this node subscribes to.
        self.param_callbacks: list[Callable[[str, Any], None]] = []
        self._param_subscriptions: dict[str, list[Callable[[str, Any], None]]] = {}
        #: This node's logger: its records (and those of its children) are published on /rosout.
        self.log = node_logger(self.name)
        self.rosout = rosout
        self.logger_services = logger_services
        self.shutdown_reason = ""
        #: set once ``aclose()`` began: late connections to closed endpoints are then expected
        self.closing = False
        self._rosout_handler: RosoutHandler | None = None
        self.shutdown_event = asyncio.Event()
        self.xmlrpc = XmlRpcClient(timeout=MASTER_TIMEOUT)
        #: The one client of the master (shares ``xmlrpc``); registration calls use its MASTER_TIMEOUT.
        self.master = MasterClient(self.master_uri, self.name, self.xmlrpc, timeout=MASTER_TIMEOUT)
        self.uri = ""
        self.tcpros_port = 0
        self.admission_limits = admission or AdmissionLimits()
        #: the TCPROS listener and every connection it accepted still open (closed by aclose())
        self._inbound = InboundConnections(self, self.admission_limits)
        self._slave: XmlRpcServer | None = None
        self._watchdog: asyncio.Task[None] | None = None
        self._started = False

    # --- lifecycle -------------------------------------------------------------------------------

    @property
    def _bind_host(self) -> str:
        return "::" if _is_ipv6(self.host) else "0.0.0.0"

    def _format_host(self) -> str:
        return f"[{self.host}]" if _is_ipv6(self.host) else self.host

    async def start(self) -> None:
        """Open the TCPROS listener and the slave API, and check that the master answers.

        Raises:
            MasterUnreachableError: no master answers at ``master_uri``.
        """
        loop = asyncio.get_running_loop()
        try:
            self.tcpros_port = self._inbound.start(self._bind_host, backlog=1024)
            self._slave = XmlRpcServer(
                SlaveApi(self).methods(), host=self._bind_host, port=0, name=f"slave {self.name}"
            )
            await self._slave.start()
            self.uri = f"http://{self._format_host()}:{self._slave.port}/"
            await self.master.get_uri()
        except BaseException:
            await self._close_servers()
            raise
        self._started = True
        _open_nodes.add(self)
        try:
            await self._start_rosout()
        except MrosError as exc:
            # As rospy: a node whose /rosout or logger services cannot be registered still runs.
            log.warning("%s: /rosout logging and logger services unavailable: %s", self.name, exc)
        except BaseException:
            await self.aclose()
            raise
        if self.watchdog_interval > 0:
            self._watchdog = loop.create_task(self._watch(), name=f"watchdog {self.name}")
        log.debug("node %s up: %s (TCPROS port %d)", self.name, self.uri, self.tcpros_port)

    async def _start_rosout(self) -> None:
        if self.rosout:
            pub = await self.advertise(
                ROSOUT_TOPIC, get_message_class("rosgraph_msgs/Log"), latch=True, queue_size=ROSOUT_QUEUE_SIZE
            )
            handler = RosoutHandler(self.name, pub, self._topic_names, asyncio.get_running_loop())
            rosout_logger = logging.getLogger(ROSOUT_LOGGER)
            if rosout_logger.level == logging.NOTSET:
                rosout_logger.setLevel(logging.INFO)  # rospy's default: loginfo reaches /rosout
            rosout_logger.addHandler(handler)
            self._rosout_handler = handler
        if self.logger_services:
            get_srv, on_get, set_srv, on_set = logger_service_handlers()
            await self.advertise_service("~get_loggers", get_srv, on_get)
            await self.advertise_service("~set_logger_level", set_srv, on_set)

    def _topic_names(self) -> list[str]:
        return sorted({*self.publishers, *self.subscribers})

    async def aclose(self) -> None:
        """Unregister every topic and service (best effort, bounded) and close every connection."""
        self.closing = True
        _open_nodes.discard(self)
        if self._rosout_handler is not None:
            logging.getLogger(ROSOUT_LOGGER).removeHandler(self._rosout_handler)
            self._rosout_handler = None
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        parts: list[Any] = [*self.subscribers.values(), *self.publishers.values(), *self.services.values()]
        await asyncio.gather(*(p.aclose() for p in parts), return_exceptions=True)
        await self._close_servers()

    async def _close_servers(self) -> None:
        await self._inbound.aclose()
        if self._slave is not None:
            await self._slave.aclose()
            self._slave = None
        await self.xmlrpc.aclose()

    async def __aenter__(self) -> Node:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # --- master ----------------------------------------------------------------------------------

    def _master(self, timeout: float) -> MasterClient:
        """A MasterClient with another per-call timeout, sharing our caller id and XML-RPC client."""
        if timeout == MASTER_TIMEOUT:
            return self.master
        return MasterClient(self.master_uri, self.name, self.xmlrpc, timeout=timeout)

    async def master_call(self, method: str, *args: Any, timeout: float = MASTER_TIMEOUT) -> Any:
        """Call any Master/Parameter Server API method with our caller id; return its value.

        A raw escape hatch for methods without a typed wrapper; ``node.master`` has the typed ones.

        Raises:
            MasterError: the master answered with a failure code.
            MasterUnreachableError: the master could not be reached.
        """
        return await self._master(timeout).call(method, *args)

    async def get_param(self, key: str) -> Any:
        """A parameter's value (name resolved for this node).

        Raises:
            MasterError: the parameter is not set.
        """
        return await self.master.get_param(self.resolve_name(key))

    async def set_param(self, key: str, value: Any) -> None:
        """Set a parameter (name resolved for this node)."""
        await self.master.set_param(self.resolve_name(key), value)

    def resolve_name(self, name: str) -> str:
        """Resolve a graph name for this node, remappings applied.

        Raises:
            InvalidNameError: the name is not legal.
        """
        return self.names.resolve(name)

    async def _unregister(self, method: str, *args: Any) -> None:
        if not self._started:
            return
        try:
            await self._master(UNREGISTER_TIMEOUT).call(method, *args)
        except MrosError as exc:
            log.info("%s: %s%r failed: %s", self.name, method, args, exc)

    async def _undo_registration(self, exc: BaseException, method: str, *args: Any) -> None:
        """A registration call failed without the master's answer (cancelled, timed out): it may have been
        registered all the same, so unregister it (bounded); a master that answered with a failure did not."""
        if not isinstance(exc, MasterError) or isinstance(exc, MasterUnreachableError):
            await self._unregister(method, *args)

    async def _watch(self) -> None:
        delay = self.watchdog_interval
        down = False
        while True:
            await asyncio.sleep(delay)
            if not (self.publishers or self.subscribers or self.services):
                continue
            try:
                uri = await self._master(max(1.0, delay * 2)).lookup_node(self.name)
                if down:
                    log.warning("%s: the master at %s is back", self.name, self.master_uri)
                    down = False
                    await self._reregister()
                elif uri != self.uri:
                    log.warning("%s: the master maps our name to %s, not %s", self.name, uri, self.uri)
                delay = self.watchdog_interval
            except MasterUnreachableError as exc:
                if not down:
                    log.warning("%s: master unreachable, will re-register when it returns: %s", self.name, exc)
                down = True
                delay = min(delay * 2, WATCHDOG_MAX_INTERVAL)
            except MasterError:
                log.warning("%s: the master does not know this node (restarted?); registering again", self.name)
                down = False
                await self._reregister()
            except Exception:
                log.exception("%s: watchdog check failed", self.name)

    async def _reregister(self) -> None:
        for pub in list(self.publishers.values()):
            try:
                await self.master.call("registerPublisher", pub.topic, pub.type, self.uri)
            except MrosError as exc:
                log.warning("%s: re-registering publisher %s failed: %s", self.name, pub.topic, exc)
        for sub in list(self.subscribers.values()):
            try:
                uris = await self.master.call("registerSubscriber", sub.topic, sub.type, self.uri)
                sub.update_publishers(list(uris) if isinstance(uris, list) else [])
            except MrosError as exc:
                log.warning("%s: re-registering subscriber %s failed: %s", self.name, sub.topic, exc)
        for srv in list(self.services.values()):
            try:
                await self.master.register_service(srv.name, self.service_uri, self.uri)
            except MrosError as exc:
                log.warning("%s: re-registering service %s failed: %s", self.name, srv.name, exc)

    def shutdown_requested(self, reason: str) -> None:
        """The master or a tool called our slave API's ``shutdown``: set ``shutdown_event``."""
        # The master gave our name to another node: stop the watchdog so we never fight over it.
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        self.shutdown_reason = reason
        self.shutdown_event.set()

    async def spin(self) -> None:
        """Wait until the node is told to shut down (``rosnode kill``), as ``rospy.spin()``.

        For an application with nothing else to await; under ``mrosd.run`` Ctrl-C or SIGTERM cancels it.
        """
        await self.shutdown_event.wait()

    def param_update(self, key: str, value: Any) -> bool:
        """A paramUpdate from the master: run the callbacks of the subscribed key it falls under.

        Returns False when this node does not subscribe to ``key`` (the slave API then answers -1).
        """
        callbacks = [
            cb
            for sub_key, cbs in self._param_subscriptions.items()
            if key == sub_key or key.startswith(sub_key.rstrip("/") + "/") or sub_key.startswith(key.rstrip("/") + "/")
            for cb in cbs
        ]
        if not callbacks:
            return False
        for cb in [*callbacks, *self.param_callbacks]:
            try:
                cb(key, value)
            except Exception:
                log.exception("%s: paramUpdate callback failed", self.name)
        return True

    async def subscribe_param(self, key: str, callback: Callable[[str, Any], None]) -> Any:
        """Subscribe to a parameter: ``callback(key, value)`` runs on every change; returns the current value.

        The value is ``{}`` when the parameter is not set (the master's answer).

        Raises:
            MasterError: the master refused the subscription.
        """
        self._check_started()
        name = self.resolve_name(key)
        first = name not in self._param_subscriptions
        self._param_subscriptions.setdefault(name, []).append(callback)
        try:
            return await self.master.subscribe_param(self.uri, name)
        except BaseException:
            if first:
                self._param_subscriptions.pop(name, None)
            raise

    async def unsubscribe_param(self, key: str) -> None:
        """Drop every callback of a parameter subscription and tell the master."""
        name = self.resolve_name(key)
        if self._param_subscriptions.pop(name, None) is not None:
            await self._unregister("unsubscribeParam", self.uri, name)

    @property
    def service_uri(self) -> str:
        return f"rosrpc://{self._format_host()}:{self.tcpros_port}"

    # --- topics and services ---------------------------------------------------------------------

    def _check_started(self) -> None:
        if not self._started:
            raise LocalProtocolError(f"node {self.name} is not started: use 'async with Node(...)' or await start()")

    async def advertise(
        self,
        topic: str,
        msg_class: Any,
        *,
        latch: bool = False,
        queue_size: int = DEFAULT_QUEUE_SIZE,
        max_message_size: int | None = None,
        max_queued_bytes: int = 0,
    ) -> Publisher:
        """Publish ``topic`` with type ``msg_class``; registers with the master.

        ``max_message_size`` (bytes, serialized): the largest message this publisher will send. Its
        same-host shared-memory pool is then made now, every page faulted in, so that neither the first
        message nor a new subscriber pays for fresh memory (``docs/shm.md``). ``max_queued_bytes``: what a
        slow subscriber's queue may hold in bytes, besides ``queue_size`` messages (0: no such bound, as in
        rospy and roscpp); the oldest go first, the newest is always kept.

        Raises:
            LocalProtocolError: the topic is already advertised by this node with another type.
            MasterError: the master refused the registration.
        """
        self._check_started()
        name = self.resolve_name(topic)
        existing = self.publishers.get(name)
        if existing is not None:
            if existing.md5sum != getattr(msg_class, "_md5sum", None):
                raise LocalProtocolError(f"{name} is already advertised by {self.name} as {existing.type}")
            return existing
        pub = Publisher(
            self,
            name,
            msg_class,
            latch=latch,
            queue_size=queue_size,
            max_message_size=max_message_size,
            max_queued_bytes=max_queued_bytes,
        )
        self.publishers[name] = pub
        try:
            if max_message_size is not None:
                await pub.shm_prepare()
            await self.master.call("registerPublisher", name, pub.type, self.uri)
        except BaseException as exc:
            self.publishers.pop(name, None)
            await self._undo_registration(exc, "unregisterPublisher", name, self.uri)
            raise
        return pub

    async def subscribe(
        self,
        topic: str,
        msg_class: Any,
        callback: Callable[[Any], Any] | None = None,
        *,
        queue_size: int = DEFAULT_QUEUE_SIZE,
        tcp_nodelay: bool = True,
        zero_copy: bool = False,
        max_leased: int = 2,
    ) -> Subscriber:
        """Subscribe to ``topic``: iterate the result, or pass ``callback`` (sync or async).

        ``zero_copy``: a message from a same-host mrosd publisher that declared its pool
        (``max_message_size``) has its large arrays (``uint8[]``, numeric) as read-only views into the
        publisher's shared memory (``np.frombuffer(msg.data, np.uint8)`` copies nothing), leased until the
        message is released (``msg.release()``, ``with msg:``) or dropped; at most ``max_leased`` at once,
        beyond which further messages are dropped (counted), never waited for. Every message then has
        ``release()``, whatever transport brought it (docs/shm.md).

        Raises:
            LocalProtocolError: this node already subscribes to the topic.
            MasterError: the master refused the registration.
        """
        self._check_started()
        name = self.resolve_name(topic)
        if name in self.subscribers:
            raise LocalProtocolError(f"{self.name} already subscribes to {name}; share that Subscriber")
        sub = Subscriber(
            self,
            name,
            msg_class,
            callback=callback,
            queue_size=queue_size,
            tcp_nodelay=tcp_nodelay,
            zero_copy=zero_copy,
            max_leased=max_leased,
        )
        self.subscribers[name] = sub
        try:
            # Raw call: a malformed publisher list is tolerated (treated as none), not an error.
            uris = await self.master.call("registerSubscriber", name, sub.type, self.uri)
        except BaseException as exc:
            self.subscribers.pop(name, None)
            sub.closed = True
            await self._undo_registration(exc, "unregisterSubscriber", name, self.uri)
            raise
        sub.update_publishers(list(uris) if isinstance(uris, list) else [])
        return sub

    async def advertise_service(self, service: str, srv_class: Any, handler: Callable[[Any], Any]) -> Service:
        """Provide ``service``; ``handler(request)`` returns the response (sync or async) or raises.

        Raises:
            LocalProtocolError: this node already provides the service.
            MasterError: the master refused the registration.
        """
        self._check_started()
        name = self.resolve_name(service)
        if name in self.services:
            raise LocalProtocolError(f"{self.name} already provides {name}")
        srv = Service(self, name, srv_class, handler)
        self.services[name] = srv
        try:
            await self.master.register_service(name, self.service_uri, self.uri)
        except BaseException as exc:
            self.services.pop(name, None)
            await self._undo_registration(exc, "unregisterService", name, self.service_uri)
            raise
        return srv

    def service_proxy(self, service: str, srv_class: Any, *, persistent: bool = False) -> ServiceProxy:
        """A client for ``service``; close it with ``aclose()`` when persistent."""
        return ServiceProxy(self, self.resolve_name(service), srv_class, persistent=persistent)

    async def endpoint_closed(self, endpoint: object) -> None:
        """A publisher, subscriber or service of ours closed: forget it and unregister it (bounded)."""
        if isinstance(endpoint, Publisher):
            if self.publishers.get(endpoint.topic) is endpoint:
                del self.publishers[endpoint.topic]
                await self._unregister("unregisterPublisher", endpoint.topic, self.uri)
        elif isinstance(endpoint, Subscriber):
            if self.subscribers.get(endpoint.topic) is endpoint:
                del self.subscribers[endpoint.topic]
                await self._unregister("unregisterSubscriber", endpoint.topic, self.uri)
        elif isinstance(endpoint, Service) and self.services.get(endpoint.name) is endpoint:
            del self.services[endpoint.name]
            await self._unregister("unregisterService", endpoint.name, self.service_uri)
