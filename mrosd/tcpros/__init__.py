"""TCPROS and nodes: sans-IO header/framing/handshake cores, then the asyncio Node, topics and services."""

from mrosd.tcpros.header import ConnectionHeader
from mrosd.tcpros.node import Node
from mrosd.tcpros.publisher import Publisher
from mrosd.tcpros.service import Service, ServiceProxy
from mrosd.tcpros.subscriber import AnyMsg, RawMessage, Subscriber

__all__ = ["AnyMsg", "ConnectionHeader", "Node", "Publisher", "RawMessage", "Service", "ServiceProxy", "Subscriber"]
