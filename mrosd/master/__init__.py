"""The ROS 1 master: Master API and Parameter Server over XML-RPC, plus a typed client.

Layers, innermost first: ``registry`` and ``params`` (pure data, return the notifications to send),
``notifier`` (per-node bounded delivery), ``api`` (thin rosmaster-compatible handlers), ``server``
(``Master``: sockets and lifecycle), ``client`` (``MasterClient`` for nodes and tools, ``watch_graph``);
``cleanup`` removes nodes whose slave API refuses connections.

The re-exports are lazy (module ``__getattr__``): every node imports ``mrosd.master.client``, which runs this
file first, and must not pay for the server's modules (``mros topic pub``'s start-up).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.master.client import GraphChange, GraphSnapshot, MasterClient, graph_changes, watch_graph
    from mrosd.master.server import DEFAULT_PORT, Master

__all__ = ["DEFAULT_PORT", "GraphChange", "GraphSnapshot", "Master", "MasterClient", "graph_changes", "watch_graph"]

_EXPORTS = {
    **dict.fromkeys(("GraphChange", "GraphSnapshot", "MasterClient", "graph_changes", "watch_graph"), "client"),
    **dict.fromkeys(("DEFAULT_PORT", "Master"), "server"),
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
