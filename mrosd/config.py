"""The daemon's configuration: a TOML file decoded into typed Structs, then environment overrides.

Precedence, lowest first: built-in defaults, the TOML file (``--config``, ``$MROSD_CONFIG``, else
``/etc/mrosd/mrosd.toml`` when it exists), then the environment (``ROS_MASTER_URI`` gives the master's port,
``MROSD_*`` variables override single keys). Every error names the offending key and the file, so that
``mrosd --check-config`` tells the operator what to fix. The ``[ixm.rules]`` table is kept opaque here: the
IXM server owns its meaning and parses it; this module only checks that it is a table.

This module performs no I/O beyond reading the one file; it knows nothing of sockets or the event loop.
"""

from __future__ import annotations

import ipaddress
import os
import re
import urllib.parse
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import msgspec

from mrosd.backports import tomllib
from mrosd.errors import ConfigError

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "MAX_DEPTH",
    "Config",
    "FleetConfig",
    "FleetLimitConfig",
    "IxmConfig",
    "LogConfig",
    "MasterConfig",
    "Ros2Config",
    "RosoutConfig",
    "WebConfig",
    "default_ixm_socket",
    "load_config",
    "parse_config",
    "part_options",
    "valid_host",
]

DEFAULT_CONFIG_PATH = Path("/etc/mrosd/mrosd.toml")

#: Tables nested deeper than this are refused before anything walks them (no recursion limit to hit).
MAX_DEPTH = 32

LogLevel = Literal["debug", "info", "warning", "error"]
Count = Annotated[int, msgspec.Meta(ge=1)]
Seconds = Annotated[float, msgspec.Meta(gt=0)]
#: seconds, where 0 switches the feature off.
SecondsOrOff = Annotated[float, msgspec.Meta(ge=0)]


class MasterConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[master]``: where the ROS master and parameter server listen, who may call them, and its caps.

    Every key not in ``DAEMON_KEYS`` is a keyword argument of ``mrosd.master.Master`` of the same name,
    passed only when set (None keeps the master's own default): adding a cap is one line here.
    """

    DAEMON_KEYS: ClassVar[frozenset[str]] = frozenset({"host", "port", "allow"})

    host: str = "0.0.0.0"
    port: int = 11311
    #: networks (CIDR) whose clients may call the master; empty means everyone who can reach the port.
    allow: list[str] = msgspec.field(default_factory=list)
    max_connections: Count | None = None
    max_connections_per_host: Count | None = None
    idle_timeout: Seconds | None = None
    notify_timeout: Seconds | None = None
    notify_queue: Count | None = None
    #: seconds between sweeps that remove nodes whose slave API refuses connections; 0 = never (as rosmaster).
    cleanup_interval: SecondsOrOff | None = None


class IxmConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[ixm]``: the shared-memory registry's Unix socket, its caps, and its access rules (opaque here).

    Every key not in ``DAEMON_KEYS`` is a keyword argument of ``mrosd.ixm.server.IxmServer`` of the same
    name, passed only when set (None keeps the server's own default): adding a cap is one line here.
    """

    DAEMON_KEYS: ClassVar[frozenset[str]] = frozenset({"enabled", "socket", "rules"})

    enabled: bool = True
    #: empty means the default search (``$MROSD_IXM_SOCKET``, ``/run/mrosd``, ``$XDG_RUNTIME_DIR``, ``/tmp``).
    socket: str = ""
    rules: dict[str, Any] = msgspec.field(default_factory=dict)
    max_clients: Count | None = None
    max_clients_per_uid: Count | None = None
    max_keys: Count | None = None
    max_keys_per_uid: Count | None = None


class RosoutConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[rosout]``: the built-in /rosout -> /rosout_agg aggregator that roscore users expect."""

    enabled: bool = True


class WebImagesConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[[web.images]]``: how the ``T/compressed`` topics the web part makes for browser clients are encoded,
    for the raw Image topics ``T`` matching one of ``topics`` (the first matching table wins; docs/web.md)."""

    topics: list[str]
    #: JPEG quality 1..100 (image_transport's default, 80)
    quality: Annotated[int, msgspec.Meta(ge=1, le=100)] = 80
    #: wider images are scaled down by a whole factor to fit (0: never; else at least 16)
    max_width: Annotated[int, msgspec.Meta(ge=0, le=16384)] = 0
    #: at most this many frames encoded a second (0: every frame the camera sends)
    max_rate: Annotated[float, msgspec.Meta(ge=0, le=240)] = 0.0


class WebConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[web]``: browser clients over WebSocket (Foxglove protocol; ``mrosd.web``, docs/web.md).

    Loopback only unless a ``token`` is set: a WebSocket reachable from the network can publish on the robot.
    """

    enabled: bool = True
    #: bind address, or a list of them (``["127.0.0.1", "::1"]``: both ports on each); any address that is
    #: not loopback needs ``token``
    host: str | list[str] = "127.0.0.1"
    #: Foxglove WebSocket port (0: any free port)
    foxglove_port: int = 8765
    #: rosbridge v2 port for roslibjs/roslibpy (0: any free port; -1: not served)
    rosbridge_port: int = 9090
    #: clients pass it as ``?token=`` in the URL or ``Authorization: Bearer``; empty: none (loopback only)
    token: str = ""
    #: names the web ports answer to besides IP literals and ``localhost`` (any other ``Host`` is refused:
    #: DNS rebinding), e.g. ``["robot.local"]``
    hostnames: list[str] = msgspec.field(default_factory=list)
    #: pages of other sites allowed to open the WebSockets (``https://app.foxglove.dev``); the page mrosd
    #: serves itself and clients that send no ``Origin`` (scripts, Foxglove desktop) need no entry
    allowed_origins: list[str] = msgspec.field(default_factory=list)
    #: shell-style globs of the topics, services and parameters clients may use
    topics: list[str] = msgspec.field(default_factory=lambda: ["*"])
    services: list[str] = msgspec.field(default_factory=lambda: ["*"])
    params: list[str] = msgspec.field(default_factory=lambda: ["*"])
    #: globs of the ``package://`` URIs clients may fetch (Foxglove's ``fetchAsset``); default: meshes,
    #: textures and URDFs (``mrosd.web.access.DEFAULT_ASSETS``); empty: the ``assets`` capability is not offered
    assets: list[str] = msgspec.field(default_factory=lambda: list(_default_assets()))
    #: largest asset served, bytes
    asset_bytes: Count | None = None
    #: bytes queued per client subscription (drop-oldest beyond)
    queue_bytes: Count | None = None
    #: bytes queued per client over all its subscriptions
    client_bytes: Count | None = None
    #: bytes queued for all clients together
    total_bytes: Count | None = None
    max_clients: Count | None = None
    #: answer tf2_web_republisher's service and action (roslibjs/roslibpy ``TFClient``) from the daemon
    tf_republisher: bool = True
    #: ``[[web.images]]`` tables: encoder settings of the ``T/compressed`` topics offered to clients
    images: list[WebImagesConfig] = msgspec.field(default_factory=list)

    def hosts(self) -> list[str]:
        """``host`` as a list, in the order given (the first is the one URLs name)."""
        return [self.host] if isinstance(self.host, str) else list(self.host)


def _default_assets() -> tuple[str, ...]:
    from mrosd.web.access import DEFAULT_ASSETS  # pure; imported here so config stays light

    return DEFAULT_ASSETS


class FleetLimitConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[[fleet.limits]]``: a rate and bandwidth cap for the sent topics matching ``topic`` (0 = none)."""

    topic: str
    max_hz: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    max_bytes_per_s: Annotated[float, msgspec.Meta(ge=0)] = 0.0


class FleetConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[fleet]``: this master shares chosen topics and services with other robots over Zenoh (docs/fleet.md).

    Off by default; checked in full by ``mrosd.fleet.options.fleet_options`` when enabled.
    """

    enabled: bool = False
    robot: str = ""
    mode: Literal["peer", "client"] = "peer"
    listen: list[str] = msgspec.field(default_factory=list)
    connect: list[str] = msgspec.field(default_factory=list)
    multicast_scouting: bool = False
    send_topics: list[str] = msgspec.field(default_factory=list)
    send_topics_exclude: list[str] = msgspec.field(default_factory=list)
    #: nothing crosses unless named: a peer may publish only into the names listed here (issue 31)
    receive_topics: list[str] = msgspec.field(default_factory=list)
    receive_topics_exclude: list[str] = msgspec.field(default_factory=list)
    send_services: list[str] = msgspec.field(default_factory=list)
    receive_services: list[str] = msgspec.field(default_factory=list)
    prefix: str = "/{robot}"
    bridge_robot: str = ""
    prefix_tf: bool = False
    queue_size: Count = 16
    max_received: Count = 256
    lease: Seconds = 3.0
    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""
    limits: list[FleetLimitConfig] = msgspec.field(default_factory=list)


class ImagesConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[images]``: ``T/compressed`` (sensor_msgs/CompressedImage, as image_transport's ``compressed`` plugin
    makes it) published into the ROS graph for each sensor_msgs/Image topic ``T`` matching a ``compressed``
    glob, encoded only while someone subscribes (``mrosd.images``, docs/images.md). Empty list: off.
    ``MROSD_IMAGES_COMPRESSED`` (comma-separated globs) overrides the list."""

    compressed: list[str] = msgspec.field(default_factory=list)
    #: JPEG quality 1..100 (the plugin's default, 80)
    quality: Annotated[int, msgspec.Meta(ge=1, le=100)] = 80
    #: wider images are scaled down by a whole factor to fit (0: never)
    max_width: Annotated[int, msgspec.Meta(ge=0)] = 0
    #: zlib level of 16-bit PNGs (the plugin's default is 9; 1 keeps up with a live depth camera)
    png_level: Annotated[int, msgspec.Meta(ge=0, le=9)] = 1


class Ros2Config(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[ros2]``: ROS 1 topics on Zenoh as rmw_zenoh's ROS 2 nodes see them (docs/ros2.md).

    Off by default. ``domain_id`` -1 means ``ROS_DOMAIN_ID`` (else 0); ``connect`` defaults to the router
    rmw_zenoh's nodes use; ``to_ros2`` lists the ROS 1 topics (globs) that cross, ``from_ros2`` the
    ROS 2 topics (globs) republished on ROS 1.
    """

    enabled: bool = False
    domain_id: Annotated[int, msgspec.Meta(ge=-1, le=232)] = -1
    connect: list[str] = msgspec.field(default_factory=lambda: ["tcp/localhost:7447"])
    listen: list[str] = msgspec.field(default_factory=list)
    to_ros2: list[str] = msgspec.field(default_factory=list)
    from_ros2: list[str] = msgspec.field(default_factory=list)
    queue_size: Count = 16
    #: "listed" (the globs), "all" (every ROS 1 topic with a publisher, at most ``max_topics``) or "demand" (a
    #: topic crosses only while the other side subscribes); from ROS 2, every mode takes only ``from_ros2``
    mode: Literal["listed", "all", "demand"] = "listed"
    #: "jazzy" (RIHS01 hashes: Jazzy, Kilted, Lyrical) or "humble" (``TypeHashNotSupported``)
    distro: Literal["jazzy", "humble"] = "jazzy"
    #: be the Zenoh router rmw_zenoh's nodes connect to (``listen`` defaults to tcp/[::]:7447)
    router: bool = False
    max_topics: Count = 256
    #: seconds a bridged service call may take, either way (rmw_zenoh's clients wait 10 s)
    service_timeout: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 10.0
    #: ros1_bridge's mapping-rule YAML files (docs/ros2.md)
    mapping_rules: list[str] = msgspec.field(default_factory=list)
    #: ROS 2 share trees (``<pkg>/msg/*.msg``) whose types are republished on ROS 1
    ros2_share: list[str] = msgspec.field(default_factory=list)
    #: TLS with client certificates for ``tls/`` endpoints (docs/ros2.md, "Trust"), as ``[fleet]``'s
    tls_root_ca: str = ""
    tls_certificate: str = ""
    tls_private_key: str = ""


class LogConfig(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``[log]``: the daemon's own log verbosity, and the log files roscore users look for.

    ``dir`` is where ``<run_id>/master.log`` and ``rosout.log`` go (``mrosd.logfiles``): empty means ROS's
    own rule (``$ROS_LOG_DIR``, else ``$ROS_HOME/log``, else ``~/.ros/log``), ``"off"`` writes no files.
    Each file rotates past ``max_bytes`` keeping ``backups`` numbered copies (rosout's 100 MiB and 10).
    """

    OFF: ClassVar[str] = "off"

    level: LogLevel = "info"
    dir: str = ""
    max_bytes: Count = 100 * 1024 * 1024
    backups: Annotated[int, msgspec.Meta(ge=0)] = 10


class Config(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """The whole configuration; each section is optional in the file."""

    master: MasterConfig = msgspec.field(default_factory=MasterConfig)
    ixm: IxmConfig = msgspec.field(default_factory=IxmConfig)
    rosout: RosoutConfig = msgspec.field(default_factory=RosoutConfig)
    web: WebConfig = msgspec.field(default_factory=WebConfig)
    log: LogConfig = msgspec.field(default_factory=LogConfig)
    fleet: FleetConfig = msgspec.field(default_factory=FleetConfig)
    images: ImagesConfig = msgspec.field(default_factory=ImagesConfig)
    ros2: Ros2Config = msgspec.field(default_factory=Ros2Config)
    #: the file this came from, or "" for defaults only (not a TOML key).
    source: str = ""


def part_options(section: MasterConfig | IxmConfig) -> dict[str, Any]:
    """The keyword arguments a section passes to its part: its set keys, minus those the daemon consumes."""
    return {
        name: value
        for name in section.__struct_fields__
        if name not in section.DAEMON_KEYS and (value := getattr(section, name)) is not None
    }


def default_ixm_socket(environ: Mapping[str, str] | None = None) -> str:
    """The IXM socket path of the architecture contract, first match wins."""
    env = os.environ if environ is None else environ
    if env.get("MROSD_IXM_SOCKET"):
        return env["MROSD_IXM_SOCKET"]
    run = Path("/run/mrosd")
    if run.is_dir() and os.access(run, os.W_OK):
        return str(run / "ixm.sock")
    xdg = env.get("XDG_RUNTIME_DIR")
    if xdg:
        return str(Path(xdg) / "mrosd" / "ixm.sock")
    return f"/tmp/mrosd-{os.getuid()}/ixm.sock"


def _convert(raw: dict[str, Any], source: str) -> Config:
    raw = dict(raw)
    raw.pop("source", None)
    try:
        cfg = msgspec.convert(raw, Config)
    except msgspec.ValidationError as exc:
        # msgspec says e.g. "Expected `int`, got `str` - at `$.master.port`"; turn the path into the TOML key.
        text = str(exc).replace("`$.", "`").replace(" - at ", " at key ")
        raise ConfigError(f"{source}: {text}") from exc
    cfg.source = source
    return cfg


_HOST_LABEL = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)")


def valid_host(host: str) -> bool:
    """True for an IPv4 or IPv6 literal or a syntactically valid host name (``999.1.1.1`` is neither)."""
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        pass
    labels = host.removesuffix(".").split(".")
    if not host or len(host) > 253 or all(label.isdigit() for label in labels):
        return False  # all-numeric names are addresses, and this one did not parse as one
    return all(_HOST_LABEL.fullmatch(label) for label in labels)


def _check_depth(raw: Any, source: str) -> None:
    """Refuse tables and arrays nested deeper than MAX_DEPTH, iteratively (a 5000-deep file is data too)."""
    stack: list[tuple[Any, str, int]] = [(raw, "", 0)]
    while stack:
        value, key, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise ConfigError(f"{source}: {key or 'the file'} is nested more than {MAX_DEPTH} levels deep")
        if isinstance(value, dict):
            stack.extend((v, f"{key}.{k}" if key else str(k), depth + 1) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((v, f"{key}[{i}]", depth + 1) for i, v in enumerate(value))


def _validate(cfg: Config) -> None:
    where = cfg.source or "configuration"
    if not 0 <= cfg.master.port <= 65535:
        raise ConfigError(f"{where}: master.port must be 0..65535, got {cfg.master.port}")
    if not valid_host(cfg.master.host):
        raise ConfigError(f"{where}: master.host is not an IP address or host name: {cfg.master.host!r}")
    if cfg.log.dir not in ("", LogConfig.OFF) and not os.path.isabs(cfg.log.dir):
        raise ConfigError(f'{where}: log.dir must be an absolute path, "off" or empty, got {cfg.log.dir!r}')
    for i, net in enumerate(cfg.master.allow):
        try:
            ipaddress.ip_network(net, strict=False)
        except ValueError as exc:
            raise ConfigError(f"{where}: master.allow[{i}] is not a network: {net!r}") from exc
    _validate_web(cfg.web, where)
    for i, pattern in enumerate(cfg.images.compressed):
        if not pattern.startswith("/"):
            raise ConfigError(
                f"{where}: images.compressed[{i}] must be a global name glob (/camera/*), got {pattern!r}"
            )


def _validate_web(web: WebConfig, where: str) -> None:
    from mrosd.web.access import is_loopback  # pure; imported here so config stays light

    if not 0 <= web.foxglove_port <= 65535:
        raise ConfigError(f"{where}: web.foxglove_port must be 0..65535, got {web.foxglove_port}")
    if not -1 <= web.rosbridge_port <= 65535:
        raise ConfigError(f"{where}: web.rosbridge_port must be 0..65535 (or -1: off), got {web.rosbridge_port}")
    for i, rule in enumerate(web.images):
        for j, pattern in enumerate(rule.topics):
            if not pattern.startswith("/"):
                raise ConfigError(
                    f"{where}: web.images[{i}].topics[{j}] must be a global name glob (/camera/*), got {pattern!r}"
                )
        if 0 < rule.max_width < 16:
            raise ConfigError(
                f"{where}: web.images[{i}].max_width must be 0 (keep) or at least 16, got {rule.max_width}"
            )
    hosts = web.hosts()
    if not hosts:
        raise ConfigError(f"{where}: web.host is an empty list: name at least one address")
    if len(set(hosts)) != len(hosts):
        raise ConfigError(f"{where}: web.host names an address twice: {hosts}")
    for host in hosts:
        if not valid_host(host):
            raise ConfigError(f"{where}: web.host is not an IP address or host name: {host!r}")
        if web.enabled and not web.token and not is_loopback(host):
            raise ConfigError(f"{where}: web.host {host!r} is not loopback: set web.token (clients must present it)")


def _bool(name: str, value: str) -> bool:
    lowered = value.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise ConfigError(f"environment: {name} must be a boolean (1/0, true/false), got {value!r}")


def _int(name: str, value: str) -> int:
    try:
        return int(value)
    except ValueError as exc:
        raise ConfigError(f"environment: {name} must be an integer, got {value!r}") from exc


def apply_environment(cfg: Config, environ: Mapping[str, str]) -> Config:
    """Apply ``ROS_MASTER_URI`` and ``MROSD_*`` overrides to ``cfg`` in place and return it."""
    uri = environ.get("ROS_MASTER_URI")
    if uri:
        parsed = urllib.parse.urlsplit(uri)
        try:
            port = parsed.port
        except ValueError as exc:
            raise ConfigError(f"environment: ROS_MASTER_URI has a bad port: {uri!r}") from exc
        if parsed.scheme != "http" or not parsed.hostname:
            raise ConfigError(f"environment: ROS_MASTER_URI must look like http://host:port/, got {uri!r}")
        cfg.master.port = 11311 if port is None else port
    if "MROSD_MASTER_HOST" in environ:
        cfg.master.host = environ["MROSD_MASTER_HOST"]
        if not valid_host(cfg.master.host):
            raise ConfigError(f"environment: MROSD_MASTER_HOST is not an IP address or host name: {cfg.master.host!r}")
    if "MROSD_MASTER_PORT" in environ:
        cfg.master.port = _int("MROSD_MASTER_PORT", environ["MROSD_MASTER_PORT"])
    if "MROSD_MASTER_ALLOW" in environ:
        cfg.master.allow = [n.strip() for n in environ["MROSD_MASTER_ALLOW"].split(",") if n.strip()]
    if environ.get("MROSD_IXM_SOCKET"):
        cfg.ixm.socket = environ["MROSD_IXM_SOCKET"]
    if "MROSD_IXM" in environ:
        cfg.ixm.enabled = _bool("MROSD_IXM", environ["MROSD_IXM"])
    if "MROSD_ROSOUT" in environ:
        cfg.rosout.enabled = _bool("MROSD_ROSOUT", environ["MROSD_ROSOUT"])
    if "MROSD_WEB" in environ:
        cfg.web.enabled = _bool("MROSD_WEB", environ["MROSD_WEB"])
    if "MROSD_WEB_HOST" in environ:
        hosts = [h.strip() for h in environ["MROSD_WEB_HOST"].split(",") if h.strip()]
        cfg.web.host = hosts[0] if len(hosts) == 1 else hosts  # "127.0.0.1,::1": both
    if "MROSD_WEB_PORT" in environ:
        cfg.web.foxglove_port = _int("MROSD_WEB_PORT", environ["MROSD_WEB_PORT"])
    if "MROSD_WEB_ROSBRIDGE_PORT" in environ:
        cfg.web.rosbridge_port = _int("MROSD_WEB_ROSBRIDGE_PORT", environ["MROSD_WEB_ROSBRIDGE_PORT"])
    if "MROSD_WEB_TOKEN" in environ:
        cfg.web.token = environ["MROSD_WEB_TOKEN"]
    if "MROSD_IMAGES_COMPRESSED" in environ:
        globs = [g.strip() for g in environ["MROSD_IMAGES_COMPRESSED"].split(",") if g.strip()]
        bad = [g for g in globs if not g.startswith("/")]
        if bad:
            raise ConfigError(
                f"environment: MROSD_IMAGES_COMPRESSED needs global name globs (/camera/*), got {bad[0]!r}"
            )
        cfg.images.compressed = globs
    if "MROSD_WEB_HOSTNAMES" in environ:
        cfg.web.hostnames = [n.strip() for n in environ["MROSD_WEB_HOSTNAMES"].split(",") if n.strip()]
    if "MROSD_WEB_ALLOWED_ORIGINS" in environ:
        cfg.web.allowed_origins = [o.strip() for o in environ["MROSD_WEB_ALLOWED_ORIGINS"].split(",") if o.strip()]
    if "MROSD_LOG_LEVEL" in environ:
        level = environ["MROSD_LOG_LEVEL"].strip().lower()
        if level not in ("debug", "info", "warning", "error"):
            raise ConfigError(f"environment: MROSD_LOG_LEVEL must be debug/info/warning/error, got {level!r}")
        cfg.log.level = level  # type: ignore[assignment]
    return cfg


def parse_config(text: str, source: str = "<string>") -> Config:
    """Decode TOML text into a validated Config (no environment applied).

    Raises:
        ConfigError: the text is not TOML, a key is unknown, or a value has the wrong type or range.
    """
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from exc
    except RecursionError as exc:  # tomllib recurses once per nesting level
        raise ConfigError(f"{source}: not valid TOML: nested too deeply (more than {MAX_DEPTH} levels)") from exc
    _check_depth(raw, source)
    cfg = _convert(raw, source)
    _validate(cfg)
    return cfg


def load_config(path: str | Path | None = None, environ: Mapping[str, str] | None = None) -> Config:
    """Read the configuration file (if any) and apply environment overrides.

    ``path`` None means ``$MROSD_CONFIG``, else ``/etc/mrosd/mrosd.toml`` when it exists, else defaults.
    An explicitly named file that does not exist is an error.

    Raises:
        ConfigError: the file is unreadable or invalid, or an environment override is malformed.
    """
    env = os.environ if environ is None else environ
    explicit = path is not None or bool(env.get("MROSD_CONFIG"))
    chosen = Path(path) if path is not None else Path(env.get("MROSD_CONFIG") or DEFAULT_CONFIG_PATH)
    if chosen.exists() or explicit:
        try:
            text = chosen.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"{chosen}: cannot read the configuration file: {exc.strerror or exc}") from exc
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{chosen}: not UTF-8 text: {exc}") from exc
        cfg = parse_config(text, str(chosen))
    else:
        cfg = Config()
    apply_environment(cfg, env)
    _validate(cfg)
    if not cfg.ixm.socket:
        cfg.ixm.socket = default_ixm_socket(env)
    return cfg
