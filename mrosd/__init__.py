"""mrosd: a small, fast ROS 1 runtime in Python.

The public asyncio API is re-exported here; see the submodules for the parts. Importing any submodule runs
this file first, so these re-exports stay lazy (module ``__getattr__``): ``import mrosd.msg`` (how ``mros msg``
and every message user starts) loads the message code in ~40 ms, where the node stack with aiohttp costs
~340 ms more (``python -X importtime``). ``mrosd.Node`` imports ``mrosd.tcpros`` on first use. Every other
package imports plainly; the pure cores that need no node live apart (``mrosd.wire``, ``mrosd.msg``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    __version__: str
    from mrosd.app import run
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
    "run",
]

#: Where each re-exported name lives.
_EXPORTS = {
    "MrosError": "mrosd.errors",
    "run": "mrosd.app",
    "Duration": "mrosd.msg",
    "Time": "mrosd.msg",
    **dict.fromkeys(
        ("AnyMsg", "Node", "Publisher", "RawMessage", "Service", "ServiceProxy", "Subscriber"), "mrosd.tcpros"
    ),
}
#: Subpackages that ``import mrosd`` used to load eagerly, still reachable as ``mrosd.<name>`` after it.
_SUBMODULES = frozenset({"errors", "master", "msg", "names", "tcpros", "xmlrpc"})


def _version() -> str:
    """The installed distribution's version (pyproject.toml's, the one source); looked up on first use."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mrosd")
    except PackageNotFoundError:  # a source tree on sys.path that was never installed
        return "0+unknown"


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if name == "__version__":
        value: Any = _version()
    elif module is not None:
        value = getattr(importlib.import_module(module), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # cached: later lookups never reach __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__, *_SUBMODULES})
