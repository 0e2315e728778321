"""dynamic_reconfigure for asyncio: ``ReconfigureClient`` and ``ReconfigureServer``, interoperable with ROS 1's.

Re-exports only; see docs/reconfigure.md.
"""

from mrosd.reconfigure.description import Description, EnumConstant, GroupSpec, Param, ReconfigureError
from mrosd.reconfigure.node import ReconfigureClient, ReconfigureServer

__all__ = [
    "Description",
    "EnumConstant",
    "GroupSpec",
    "Param",
    "ReconfigureClient",
    "ReconfigureError",
    "ReconfigureServer",
]
