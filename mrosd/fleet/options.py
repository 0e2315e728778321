"""What the fleet part is told (robot name, Zenoh endpoints, what crosses) and the Zenoh configuration it
makes of it: pure, so a wrong setting is refused with its key before any socket opens."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

from mrosd.config import FleetConfig
from mrosd.errors import ConfigError
from mrosd.fleet.keys import NameFilter, RenameRule, glob_match
from mrosd.fleet.limits import MAX_MESSAGE_SIZE, RateLimit

_ROBOT = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_ENDPOINT = re.compile(r"^(tcp|tls|udp|quic)/.+:\d+$")
#: Messages queued per topic between the event loop and Zenoh, in either direction, before the oldest goes.
DEFAULT_QUEUE = 16
#: Remote topics plus services published here at most: each one is a registration at the master and a
#: listening socket, and anything that reaches the Zenoh port can announce names without end.
DEFAULT_MAX_RECEIVED = 256
#: Seconds without a word from a peer before its link counts as lost (Zenoh's lease): a cut is seen this fast.
DEFAULT_LEASE = 3.0
#: Upper bound of the pause between two attempts to reach a configured endpoint again after a loss.
DEFAULT_RETRY_MAX = 1.0


@dataclass(frozen=True, slots=True)
class TopicLimit:
    """A rate and bandwidth limit for the topics matching ``pattern`` (0 = no limit)."""

    pattern: str
    max_hz: float = 0.0
    max_bytes_per_s: float = 0.0

    def make(self) -> RateLimit:
        return RateLimit(max_hz=self.max_hz, max_bytes_per_s=self.max_bytes_per_s)


@dataclass(frozen=True, slots=True)
class FleetOptions:
    """The fleet part's settings (``[fleet]`` in mrosd.toml; docs/fleet.md).

    ``robot`` names this robot: it is the bridge namespace of everything it announces, and the prefix under
    which other robots see its topics. ``send_*`` are local names offered to the fleet, ``receive_*`` are local
    names (after renaming, e.g. ``/robot1/**``) taken from it.
    """

    robot: str
    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    send_topics: NameFilter = field(default_factory=NameFilter)
    receive_topics: NameFilter = field(default_factory=NameFilter)
    send_services: NameFilter = field(default_factory=NameFilter)
    receive_services: NameFilter = field(default_factory=NameFilter)
    rename: RenameRule = field(default_factory=RenameRule)
    #: prefix the frames of other robots' /tf and /tf_static with their names (mrosd/fleet/frames.py)
    prefix_tf: bool = False
    limits: tuple[TopicLimit, ...] = ()
    queue_size: int = DEFAULT_QUEUE
    max_received: int = DEFAULT_MAX_RECEIVED
    lease: float = DEFAULT_LEASE
    retry_max: float = DEFAULT_RETRY_MAX
    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""

    def __post_init__(self) -> None:
        if not _ROBOT.match(self.robot):
            raise ConfigError(f"fleet.robot: {self.robot!r} must be a ROS name segment (letters, digits, _)")
        if self.mode not in ("peer", "client"):
            raise ConfigError(f"fleet.mode: {self.mode!r} must be 'peer' or 'client'")
        if self.mode == "client" and not self.connect:
            raise ConfigError("fleet.connect: client mode needs at least one endpoint (a router or a peer)")
        for key, endpoints in (("listen", self.listen), ("connect", self.connect)):
            for ep in endpoints:
                if not _ENDPOINT.match(ep):
                    raise ConfigError(f"fleet.{key}: {ep!r} is not a Zenoh endpoint like tcp/192.168.1.10:7447")
        if self.queue_size < 1:
            raise ConfigError("fleet.queue_size must be at least 1")
        if self.max_received < 1:
            raise ConfigError("fleet.max_received must be at least 1")
        if not 0.5 <= self.lease <= 60:
            raise ConfigError("fleet.lease must be between 0.5 and 60 seconds")
        uses_tls = any(ep.startswith(("tls/", "quic/")) for ep in (*self.listen, *self.connect))
        if uses_tls and not self.tls_root_ca:
            raise ConfigError("fleet.tls_root_ca: tls/ and quic/ endpoints need the CA certificate file")
        if any(ep.startswith(("tls/", "quic/")) for ep in self.listen) and not (
            self.tls_certificate and self.tls_private_key
        ):
            raise ConfigError(
                "fleet.tls_certificate: a tls/ or quic/ listen endpoint needs tls_certificate and tls_private_key"
            )

    def limit_for(self, topic: str) -> RateLimit | None:
        """A fresh limit for ``topic`` from the first matching pattern, or None."""
        for lim in self.limits:
            if glob_match(lim.pattern, topic):
                return lim.make()
        return None


def zenoh_settings(opts: FleetOptions) -> list[tuple[str, str]]:
    """``(path, json5 value)`` pairs for ``zenoh.Config.insert_json5``.

    Multicast scouting stays off unless asked (a robot does not advertise itself on every network it joins);
    the lease is short so a cut link is noticed within seconds, and reconnection attempts to the configured
    endpoints never stop and never wait longer than ``retry_max``; no message over ``MAX_MESSAGE_SIZE`` is
    rebuilt. (``connect/timeout_ms`` stays Zenoh's: set to 0 it also ends the background attempts, and a robot
    started before its peer would never link.)
    """
    lease_ms = int(opts.lease * 1000)
    retry_ms = int(opts.retry_max * 1000)
    out = [
        ("mode", json.dumps(opts.mode)),
        ("listen/endpoints", json.dumps(list(opts.listen))),
        ("connect/endpoints", json.dumps(list(opts.connect))),
        ("scouting/multicast/enabled", json.dumps(opts.multicast_scouting)),
        ("transport/link/tx/lease", json.dumps(lease_ms)),
        ("transport/link/tx/keep_alive", json.dumps(4)),
        (
            "connect/retry",
            json.dumps({"period_init_ms": min(250, retry_ms), "period_max_ms": retry_ms, "period_increase_factor": 2}),
        ),
        ("listen/retry", json.dumps({"period_init_ms": min(250, retry_ms), "period_max_ms": retry_ms})),
        ("transport/link/rx/max_message_size", json.dumps(MAX_MESSAGE_SIZE)),
    ]
    if opts.tls_root_ca:
        out.append(("transport/link/tls/root_ca_certificate", json.dumps(opts.tls_root_ca)))
    if opts.tls_certificate:
        out.append(("transport/link/tls/listen_certificate", json.dumps(opts.tls_certificate)))
        out.append(("transport/link/tls/connect_certificate", json.dumps(opts.tls_certificate)))
    if opts.tls_private_key:
        out.append(("transport/link/tls/listen_private_key", json.dumps(opts.tls_private_key)))
        out.append(("transport/link/tls/connect_private_key", json.dumps(opts.tls_private_key)))
    if opts.tls_certificate and opts.tls_private_key:
        # Both ends show a certificate of the fleet's CA: knowing the (public) CA is not enough to join.
        out.append(("transport/link/tls/enable_mtls", json.dumps(True)))
    return out


def fleet_options(section: FleetConfig, source: str = "configuration") -> FleetOptions:
    """The options of a ``[fleet]`` section.

    Raises:
        ConfigError: naming the key: no robot name, a bad endpoint, mode, queue or lease.
    """
    if not section.robot:
        raise ConfigError(f"{source}: fleet.robot must name this robot (it prefixes its topics on the others)")
    try:
        return FleetOptions(
            robot=section.robot,
            mode=section.mode,
            listen=tuple(section.listen),
            connect=tuple(section.connect),
            multicast_scouting=section.multicast_scouting,
            send_topics=NameFilter(tuple(section.send_topics), tuple(section.send_topics_exclude)),
            receive_topics=NameFilter(tuple(section.receive_topics), tuple(section.receive_topics_exclude)),
            send_services=NameFilter(tuple(section.send_services)),
            receive_services=NameFilter(tuple(section.receive_services)),
            rename=RenameRule(prefix=section.prefix, wildcard_robot=section.bridge_robot),
            prefix_tf=section.prefix_tf,
            limits=tuple(TopicLimit(lim.topic, lim.max_hz, lim.max_bytes_per_s) for lim in section.limits),
            queue_size=section.queue_size,
            max_received=section.max_received,
            lease=section.lease,
            tls_root_ca=section.tls_root_ca,
            tls_certificate=section.tls_certificate,
            tls_private_key=section.tls_private_key,
        )
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from exc
