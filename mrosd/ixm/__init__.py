"""IXM: the shared-memory data registry (after the IXM paper), with enforced access and wake-ups.

Re-exports only; see docs/ixm.md. Daemon side: ``mrosd.ixm.server.IxmServer``; client side:
``IxmClient`` (blocking) and ``AsyncIxmClient`` (asyncio).
"""

from mrosd.ixm.client import AsyncIxmClient, AsyncIxmKey, IxmClient, IxmKey
from mrosd.ixm.rules import AccessRules, parse_rules

__all__ = ["AccessRules", "AsyncIxmClient", "AsyncIxmKey", "IxmClient", "IxmKey", "parse_rules"]
