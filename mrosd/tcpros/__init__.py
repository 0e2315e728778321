"""TCPROS nodes on asyncio: ``Node``, its publishers, subscribers, services and slave XML-RPC API.

The sans-IO wire cores these build on live in ``mrosd.wire``, so this package imports its node stack plainly.
"""

from __future__ import annotations

from mrosd.tcpros.node import Node
from mrosd.tcpros.publisher import Publisher
from mrosd.tcpros.service import Service, ServiceProxy
from mrosd.tcpros.subscriber import AnyMsg, RawMessage, Subscriber
from mrosd.wire.header import ConnectionHeader

__all__ = ["AnyMsg", "ConnectionHeader", "Node", "Publisher", "RawMessage", "Service", "ServiceProxy", "Subscriber"]
