"""mrosd: a small, fast ROS 1 runtime in Python.

The public asyncio API is re-exported here; see the submodules for the parts.
"""

from __future__ import annotations

from mrosd.errors import MrosError

__all__ = ["MrosError"]
__version__ = "0.1.0"
