"""What a node's children need from the node that owns them, as small protocols.

Publishers, subscribers, services, service proxies and the slave API do not call into ``Node``'s private
state: each one holds an owner typed by one of these protocols and reports to it through public methods
(a child reports its own close with ``endpoint_closed``, as goroslib's publisher reports its close to its
node). ``Node`` implements all of them; a test or another container can implement just the one a child
needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient
    from mrosd.xmlrpc import XmlRpcClient


class EndpointOwner(Protocol):
    """The owner of a publisher, subscriber, service or service proxy."""

    #: The owner's resolved node name: the callerid of every connection header and API call.
    name: str
    #: The shared XML-RPC client (requestTopic to publishers).
    xmlrpc: XmlRpcClient
    #: The owner's client of the master (service lookups).
    master: MasterClient

    async def endpoint_closed(self, endpoint: object) -> None:
        """A child has closed: forget it and unregister it from the master (bounded, best effort)."""


class SlaveOwner(Protocol):
    """The node state the slave API answers from, and the two events it reports."""

    name: str
    #: The slave API's own URI (getUri).
    uri: str
    master_uri: str
    host: str
    tcpros_port: int

    @property
    def publishers(self) -> Mapping[str, Any]: ...

    @property
    def subscribers(self) -> Mapping[str, Any]: ...

    @property
    def services(self) -> Mapping[str, Any]: ...

    def shutdown_requested(self, reason: str) -> None:
        """The master (or a tool) asked this node to shut down."""

    def param_update(self, key: str, value: Any) -> bool:
        """A subscribed parameter changed; False when this node does not subscribe to ``key``."""
