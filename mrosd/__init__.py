"""mrosd: a small, fast ROS 1 runtime in Python.

The public asyncio API is re-exported here; see the submodules for the parts.
"""

from __future__ import annotations

from mrosd.errors import MrosError
from mrosd.msg import Duration, Time
from mrosd.tcpros import AnyMsg, Node, Publisher, RawMessage, Service, ServiceProxy, Subscriber

__all__ = [
    "AnyMsg",
    "Duration",
    "MrosError",
    "Node",
    "Publisher",
    "RawMessage",
    "Service",
    "ServiceProxy",
    "Subscriber",
    "Time",
]
__version__ = "0.1.0"
