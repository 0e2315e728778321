"""Who may use shared memory with whom, and the requestTopic exchange that sets it up (pure functions).

ROS 1 lets a subscriber offer several protocols in ``requestTopic``, best first; the publisher answers with
the first one it supports. A mrosd subscriber offers ``["MROSSHM", version, boot_id, netns, uid]`` before
``["TCPROS"]``; rospy and roscpp skip a protocol they do not know (both iterate the list and take the first
one they implement) and answer TCPROS as always. A mrosd publisher answers
``["MROSSHM", version, address, token]`` when the offer comes from the same kernel (boot id), the same
network namespace (abstract Unix sockets live there) and a uid it lets read its memory; otherwise it goes on
down the list to TCPROS. The offer is only a hint: the publisher checks the subscriber's uid again from the
kernel (``SO_PEERCRED``) when it connects, and the token ties that connection to this requestTopic answer.

Same host is decided by the boot id (``/proc/sys/kernel/random/boot_id``), not the hostname: two
containers can share a hostname and two names can point at one machine; a memfd can only be passed between
processes of one running kernel.
"""

from __future__ import annotations

import os
from typing import Any

import msgspec

from mrosd.errors import RemoteProtocolError

__all__ = [
    "PROTOCOL",
    "TRANSPORT",
    "TRUSTED_UIDS_ENV",
    "VERSION",
    "HostIdentity",
    "ShmAnswer",
    "ShmOffer",
    "choose_protocol",
    "local_identity",
    "parse_answer",
    "permitted_uid",
    "publisher_answer",
    "subscriber_offer",
]

#: The protocol name in requestTopic (offers and answers).
PROTOCOL = "MROSSHM"
#: The transport name getBusInfo reports for a shared-memory connection.
TRANSPORT = "SHMROS"
#: 2: acknowledgement pages and the publisher's queue (an Attached carries three descriptors, ring layout v2).
#: 3: wake-ups through a socket pair the publisher makes instead of an eventfd each way (Attach carries no
#: descriptor), so that neither side can make the other's wake-up block (issue 24).
#: 4: ring layout v3 (a directory from message numbers to slots, so that the publisher skips slots a subscriber
#: holds a lease on, issue 25) and acknowledgement pages that list leases.
#: Peers of another version do not share memory: they find each other's offer unknown and use TCPROS.
VERSION = 4
#: Comma-separated uids whose nodes may read (subscriber side: write) our topics' memory, besides ours and root.
TRUSTED_UIDS_ENV = "MROSD_SHM_TRUSTED_UIDS"
#: Turns the shared-memory transport off for this process when set to 0.
ENABLE_ENV = "MROSD_SHM"

_BOOT_ID = "/proc/sys/kernel/random/boot_id"


class HostIdentity(msgspec.Struct, frozen=True):
    """What makes two processes able to share memory: one kernel, one network namespace, and their uid."""

    boot_id: str
    netns: str
    uid: int


class ShmOffer(msgspec.Struct, frozen=True):
    """A subscriber's shared-memory offer, as received in requestTopic."""

    version: int
    host: HostIdentity


class ShmAnswer(msgspec.Struct, frozen=True):
    """A publisher's shared-memory answer: where to attach and the token to show."""

    version: int
    address: str
    token: str


def local_identity() -> HostIdentity | None:
    """This process's identity, or None where it cannot be known (no /proc: then no shared memory)."""
    try:
        with open(_BOOT_ID, encoding="ascii") as f:
            boot_id = f.read().strip()
        netns = str(os.stat("/proc/self/ns/net").st_ino)
    except OSError:
        return None
    if not boot_id:
        return None
    return HostIdentity(boot_id=boot_id, netns=netns, uid=os.geteuid())


def trusted_uids(environ: dict[str, str] | None = None) -> frozenset[int]:
    """Root, our effective uid, and ``$MROSD_SHM_TRUSTED_UIDS`` (entries that are not integers are ignored)."""
    env = os.environ if environ is None else environ
    uids = {0, os.geteuid()}
    for item in env.get(TRUSTED_UIDS_ENV, "").replace(",", " ").split():
        if item.isdigit():
            uids.add(int(item))
    return frozenset(uids)


def permitted_uid(uid: int, trusted: frozenset[int]) -> bool:
    """May a peer of ``uid`` share a topic's memory with us?"""
    return uid in trusted


def enabled(environ: dict[str, str] | None = None) -> bool:
    """True unless ``MROSD_SHM=0`` (or false/no/off): this process offers and answers shared memory to
    same-host mrosd peers (docs/shm.md). Off, every connection is plain TCPROS, as between any other peers.
    """
    env = os.environ if environ is None else environ
    return env.get(ENABLE_ENV, "1").strip().lower() not in ("0", "false", "no", "off")


def subscriber_offer(identity: HostIdentity) -> list[Any]:
    """The protocol entry a subscriber puts before ``["TCPROS"]`` in requestTopic (XML-RPC safe values)."""
    return [PROTOCOL, VERSION, identity.boot_id, identity.netns, identity.uid]


def _parse_offer(entry: Any) -> ShmOffer | None:
    if not isinstance(entry, list) or len(entry) < 5 or entry[0] != PROTOCOL:
        return None
    version, boot_id, netns, uid = entry[1:5]
    if not (isinstance(version, int) and isinstance(boot_id, str) and isinstance(netns, str) and isinstance(uid, int)):
        return None
    if isinstance(uid, bool) or isinstance(version, bool):
        return None
    return ShmOffer(version=version, host=HostIdentity(boot_id=boot_id, netns=netns, uid=uid))


def choose_protocol(
    protocols: list[Any], local: HostIdentity | None, trusted: frozenset[int], shm_available: bool = True
) -> tuple[str, ShmOffer | None] | None:
    """The publisher's choice, best first as the subscriber listed them: ("MROSSHM", offer), ("TCPROS", None)
    or None when nothing offered is supported.

    A shared-memory offer is taken only from the same boot id and network namespace, a version we speak
    and a uid in ``trusted``; any other offer is skipped as rospy skips protocols it does not know.
    """
    for entry in protocols:
        if not isinstance(entry, list) or not entry:
            continue
        if entry[0] == "TCPROS":
            return "TCPROS", None
        if entry[0] == PROTOCOL and shm_available and local is not None:
            offer = _parse_offer(entry)
            if (
                offer is not None
                and offer.version == VERSION
                and offer.host.boot_id == local.boot_id
                and offer.host.netns == local.netns
                and permitted_uid(offer.host.uid, trusted)
            ):
                return PROTOCOL, offer
    return None


def publisher_answer(address: str, token: str) -> list[Any]:
    """The protocol parameters of the publisher's requestTopic answer for shared memory."""
    return [PROTOCOL, VERSION, address, token]


def parse_answer(params: Any) -> ShmAnswer | None:
    """The subscriber's reading of requestTopic's protocol parameters: an answer, or None for anything else
    (TCPROS as today).

    Raises:
        RemoteProtocolError: the publisher answered MROSSHM with parameters we cannot use.
    """
    if not isinstance(params, list) or not params or params[0] != PROTOCOL:
        return None
    if len(params) < 4:
        raise RemoteProtocolError(f"{PROTOCOL} answer has {len(params)} fields, expected 4")
    version, address, token = params[1:4]
    if version != VERSION or isinstance(version, bool):
        raise RemoteProtocolError(f"{PROTOCOL} answer of version {version!r}; we speak {VERSION}")
    if not isinstance(address, str) or not address.startswith("@") or not 1 < len(address) <= 100:
        raise RemoteProtocolError(f"{PROTOCOL} answer has a bad address {address!r}")
    if not isinstance(token, str) or not 16 <= len(token) <= 128:
        raise RemoteProtocolError(f"{PROTOCOL} answer has a bad token")
    return ShmAnswer(version=version, address=address, token=token)
