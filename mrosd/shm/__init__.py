"""Shared-memory topic transport between mrosd nodes on one host (see docs/shm.md).

``mrosd.tcpros`` imports this package lazily, only when a requestTopic offers or answers ``MROSSHM``; so the
re-exports below are lazy too (module ``__getattr__``), or ``mrosd.shm.views`` (every subscriber's) would load
both endpoints, the IXM client and the configuration at every node's start.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.shm.negotiate import (
        PROTOCOL,
        TRANSPORT,
        HostIdentity,
        ShmAnswer,
        choose_protocol,
        local_identity,
        parse_answer,
        publisher_answer,
        subscriber_offer,
    )
    from mrosd.shm.publisher import ShmPublisherEndpoint
    from mrosd.shm.subscriber import ShmSubscriberConnection, ShmView

__all__ = [
    "PROTOCOL",
    "TRANSPORT",
    "HostIdentity",
    "ShmAnswer",
    "ShmPublisherEndpoint",
    "ShmSubscriberConnection",
    "ShmView",
    "choose_protocol",
    "local_identity",
    "parse_answer",
    "publisher_answer",
    "subscriber_offer",
]

_SUBMODULE = {
    **dict.fromkeys(
        (
            "PROTOCOL",
            "TRANSPORT",
            "HostIdentity",
            "ShmAnswer",
            "choose_protocol",
            "local_identity",
            "parse_answer",
            "publisher_answer",
            "subscriber_offer",
        ),
        "negotiate",
    ),
    "ShmPublisherEndpoint": "publisher",
    "ShmSubscriberConnection": "subscriber",
    "ShmView": "subscriber",
}


def __getattr__(name: str) -> Any:
    module = _SUBMODULE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
