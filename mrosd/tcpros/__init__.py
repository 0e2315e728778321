"""TCPROS and nodes: sans-IO header/framing/handshake cores, then the asyncio Node, topics and services.

The re-exports are lazy (module ``__getattr__``), so importing a sans-IO core such as
``mrosd.tcpros.framing`` does not load the asyncio stack or aiohttp.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.tcpros.header import ConnectionHeader
    from mrosd.tcpros.node import Node
    from mrosd.tcpros.publisher import Publisher
    from mrosd.tcpros.service import Service, ServiceProxy
    from mrosd.tcpros.subscriber import AnyMsg, RawMessage, Subscriber

__all__ = ["AnyMsg", "ConnectionHeader", "Node", "Publisher", "RawMessage", "Service", "ServiceProxy", "Subscriber"]

_EXPORTS = {
    "AnyMsg": "mrosd.tcpros.subscriber",
    "ConnectionHeader": "mrosd.tcpros.header",
    "Node": "mrosd.tcpros.node",
    "Publisher": "mrosd.tcpros.publisher",
    "RawMessage": "mrosd.tcpros.subscriber",
    "Service": "mrosd.tcpros.service",
    "ServiceProxy": "mrosd.tcpros.service",
    "Subscriber": "mrosd.tcpros.subscriber",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # cached: later lookups never reach __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
