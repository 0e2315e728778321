"""Shared-memory topic transport between mrosd nodes on one host (see docs/shm.md).

``mrosd.tcpros`` imports this package lazily, only when a requestTopic offers or answers ``MROSSHM``.
"""

from __future__ import annotations

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
