"""The ros2 part's checked settings and the Zenoh configuration they make (no I/O).

``router = true`` makes the bridge's own session the Zenoh router rmw_zenoh's nodes connect to
(``rmw_zenohd``'s part: mode ``router``, listening on ``tcp/[::]:7447`` unless ``listen`` says otherwise), so a
robot with no ROS 2 install serves the ROS 2 machines that join it. Otherwise the bridge is a Zenoh ``client`` of
the router it dials, or a ``peer`` others may dial when ``listen`` is set. ``distro = "humble"`` puts rmw_zenoh's
Humble placeholder ``TypeHashNotSupported`` where Jazzy puts the RIHS01 hash.
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

    @property
    def humble(self) -> bool:
        return self.distro == "humble"


def ros2_options(cfg: Ros2Config, environ: Mapping[str, str] | None = None) -> Ros2Options:
    """``[ros2]`` -> options; ``domain_id`` -1 reads ``ROS_DOMAIN_ID`` (else 0); with ``router`` the default
    ``connect`` (the router we now are) is dropped and ``listen`` defaults to rmw_zenohd's endpoint.

    Raises:
        ConfigError: ``ROS_DOMAIN_ID`` is not a number from 0 to 232, or a mapping rules file is wrong.
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
        # rmw_zenoh's session config stamps every sample; TRANSIENT_LOCAL's advanced publisher needs it
        config.insert_json5("timestamping/enabled", "true")
    except Exception as exc:
        raise ConfigError(f"ros2: Zenoh refused the configuration: {exc}") from exc
    return config
