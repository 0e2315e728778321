"""The ROS 1 master: Master API and Parameter Server over XML-RPC, plus a typed client.

Layers, innermost first: ``registry`` and ``params`` (pure data, return the notifications to send),
``notifier`` (per-node bounded delivery), ``api`` (thin rosmaster-compatible handlers), ``server``
(``Master``: sockets and lifecycle), ``client`` (``MasterClient`` for nodes and tools, ``watch_graph``);
``cleanup`` removes nodes whose slave API refuses connections.
"""

from __future__ import annotations

from mrosd.master.client import GraphChange, GraphSnapshot, MasterClient, graph_changes, watch_graph
from mrosd.master.server import DEFAULT_PORT, Master

__all__ = ["DEFAULT_PORT", "GraphChange", "GraphSnapshot", "Master", "MasterClient", "graph_changes", "watch_graph"]
