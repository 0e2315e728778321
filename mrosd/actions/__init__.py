"""actionlib for asyncio: ``ActionClient`` and ``ActionServer``, wire-compatible with ROS 1's actionlib.

Re-exports only; see docs/actions.md.
"""

from mrosd.actions.client import ActionClient, ClientGoal
from mrosd.actions.server import ActionServer, ServerGoal
from mrosd.actions.spec import ActionSpec
from mrosd.actions.status import Status

__all__ = ["ActionClient", "ActionServer", "ActionSpec", "ClientGoal", "ServerGoal", "Status"]
