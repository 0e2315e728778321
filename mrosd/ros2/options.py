"""The ros2 part's checked settings and the Zenoh configuration they make (no I/O).

``router = true`` makes the bridge's own session the Zenoh router rmw_zenoh's nodes connect to
(``rmw_zenohd``'s part: mode ``router``, listening on ``tcp/[::]:7447`` unless ``listen`` says otherwise), so a
robot with no ROS 2 install serves the ROS 2 machines that join it. Otherwise the bridge is a Zenoh ``client`` of
the router it dials, or a ``peer`` others may dial when ``listen`` is set. ``distro = "humble"`` puts rmw_zenoh's
Humble placeholder ``TypeHashNotSupported`` where Jazzy puts the RIHS01 hash. ``tls_root_ca``,
``tls_certificate`` and ``tls_private_key`` make ``tls/`` endpoints mutual TLS, as zenoh's own configuration
names it (``transport/link/tls``: ``root_ca_certificate``, ``listen_*`` and ``connect_*`` certificate and key,
``enable_mtls``), so a session without a certificate of that CA cannot link at all.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Literal

import msgspec

from mrosd.errors import ConfigError
from mrosd.ros2.mapping import load_mapping_rules

if TYPE_CHECKING:
    from mrosd.config import Ros2Config

__all__ = ["DEFAULT_CONNECT", "ROUTER_LISTEN", "Ros2Options", "ros2_options", "zenoh_config", "zenoh_mode"]

#: where rmw_zenoh's nodes find their router
DEFAULT_CONNECT = ("tcp/localhost:7447",)
#: what rmw_zenohd listens on (its DEFAULT_RMW_ZENOH_ROUTER_CONFIG)
ROUTER_LISTEN = ("tcp/[::]:7447",)
#: the bridge node's name on both sides
NODE_NAME = "mrosd_ros2"
#: topics bridged ROS 1 -> ROS 2 at most in mode "all" (each holds a TCPROS subscription and a publisher)
MAX_ALL_TOPICS = 256
#: the biggest Zenoh message the session reassembles from a link (Zenoh's default, and rmw_zenohd's, is 1 GiB:
#: any peer could make it hold that much per link before the bridge sees a byte); above the biggest sample the
#: bridge takes (``inbound.MAX_SAMPLE_BYTES``) and service body (``services.MAX_SERVICE_BODY``)
MAX_MESSAGE_SIZE = 64 * 1024 * 1024

Mode = Literal["listed", "all", "demand"]
Distro = Literal["jazzy", "humble"]


class Ros2Options(msgspec.Struct, frozen=True, kw_only=True):
    """The checked settings of the ros2 part (``ros2_options`` builds them from ``[ros2]``)."""

    domain_id: int = 0
    connect: tuple[str, ...] = DEFAULT_CONNECT
    listen: tuple[str, ...] = ()
    to_ros2: tuple[str, ...] = ()
    from_ros2: tuple[str, ...] = ()
    queue_size: int = 16
    node_name: str = NODE_NAME
    mode: Mode = "listed"
    distro: Distro = "jazzy"
    router: bool = False
    max_topics: int = MAX_ALL_TOPICS
    service_timeout: float = 10.0
    #: ros1_bridge's mapping-rule YAML files
    mapping_rules: tuple[str, ...] = ()
    #: ROS 2 share trees whose ``<pkg>/msg/*.msg`` types may cross to ROS 1
    ros2_share: tuple[str, ...] = ()
    #: PEM files: the CA every peer's certificate must be signed by, this end's certificate and its key
    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""

    @property
    def humble(self) -> bool:
        return self.distro == "humble"


def ros2_options(cfg: Ros2Config, environ: Mapping[str, str] | None = None) -> Ros2Options:
    """``[ros2]`` -> options; ``domain_id`` -1 reads ``ROS_DOMAIN_ID`` (else 0); with ``router`` the default
    ``connect`` (the router we now are) is dropped and ``listen`` defaults to rmw_zenohd's endpoint.

    Raises:
        ConfigError: ``ROS_DOMAIN_ID`` is not a number from 0 to 232, a mapping rules file is wrong, or a
            ``tls/`` endpoint lacks its CA (or, listening, its certificate and key).
    """
    load_mapping_rules(cfg.mapping_rules)  # a bad file is one line at start, not a surprise at the first topic
    env = os.environ if environ is None else environ
    domain = cfg.domain_id
    if domain < 0:
        text = env.get("ROS_DOMAIN_ID", "") or "0"
        if not text.isdigit() or int(text) > 232:
            raise ConfigError(f"ROS_DOMAIN_ID={text!r}: a ROS 2 domain is a number from 0 to 232")
        domain = int(text)
    connect, listen = tuple(cfg.connect), tuple(cfg.listen)
    if cfg.router:
        connect = () if connect == DEFAULT_CONNECT else connect
        listen = listen or ROUTER_LISTEN
    if any(ep.startswith(("tls/", "quic/")) for ep in (*listen, *connect)) and not cfg.tls_root_ca:
        raise ConfigError("ros2.tls_root_ca: tls/ and quic/ endpoints need the CA certificate file")
    if any(ep.startswith(("tls/", "quic/")) for ep in listen) and not (cfg.tls_certificate and cfg.tls_private_key):
        raise ConfigError(
            "ros2.tls_certificate: a tls/ or quic/ listen endpoint needs tls_certificate and tls_private_key"
        )
    return Ros2Options(
        domain_id=domain,
        connect=connect,
        listen=listen,
        to_ros2=tuple(cfg.to_ros2),
        from_ros2=tuple(cfg.from_ros2),
        queue_size=cfg.queue_size,
        mode=cfg.mode,
        distro=cfg.distro,
        router=cfg.router,
        max_topics=cfg.max_topics,
        service_timeout=cfg.service_timeout,
        mapping_rules=tuple(cfg.mapping_rules),
        ros2_share=tuple(cfg.ros2_share),
        tls_root_ca=cfg.tls_root_ca,
        tls_certificate=cfg.tls_certificate,
        tls_private_key=cfg.tls_private_key,
    )


def zenoh_mode(options: Ros2Options) -> str:
    """``router`` with ``router = true``; else a ``client`` of the router it dials (rmw_zenoh's peers listen on
    localhost only, so a peer on another host would learn of them and never reach them:
    tests/netns/test_ros2_link.py), or a ``peer`` others may dial when ``listen`` is set."""
    if options.router:
        return "router"
    return "peer" if options.listen else "client"


def zenoh_config(zenoh: Any, options: Ros2Options) -> Any:
    """The session's ``zenoh.Config``.

    Raises:
        ConfigError: Zenoh refuses an endpoint or a setting.
    """
    config = zenoh.Config()
    try:
        config.insert_json5("mode", f'"{zenoh_mode(options)}"')
        config.insert_json5("connect/endpoints", msgspec.json.encode(list(options.connect)).decode())
        config.insert_json5("listen/endpoints", msgspec.json.encode(list(options.listen)).decode())
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("transport/link/rx/max_message_size", str(MAX_MESSAGE_SIZE))
        # rmw_zenoh's session config stamps every sample; TRANSIENT_LOCAL's advanced publisher needs it
        config.insert_json5("timestamping/enabled", "true")
        tls = {
            "root_ca_certificate": options.tls_root_ca,
            "listen_certificate": options.tls_certificate,
            "connect_certificate": options.tls_certificate,
            "listen_private_key": options.tls_private_key,
            "connect_private_key": options.tls_private_key,
        }
        for key, value in tls.items():
            if value:
                config.insert_json5(f"transport/link/tls/{key}", msgspec.json.encode(value).decode())
        if options.tls_certificate and options.tls_private_key:
            # every end shows a certificate of the CA: an address and a port are not enough to link
            config.insert_json5("transport/link/tls/enable_mtls", "true")
    except Exception as exc:
        raise ConfigError(f"ros2: Zenoh refused the configuration: {exc}") from exc
    return config
