"""The ROS 1 master: Master API and Parameter Server over XML-RPC, plus a typed client.

``Master`` (server) lives in ``mrosd.master.server``; ``MasterClient`` in ``mrosd.master.client``.
"""

from __future__ import annotations
