"""What browser clients may see and touch: topic, service and parameter allow-lists, the token rule.

Pure data. The globs are shell-style (``fnmatch``) over resolved graph names (``/camera/*``, ``/rosout*``),
and over whole URIs for assets (``package://*.stl``); ``*`` alone allows everything, an empty list allows
nothing (and, for assets, the server does not offer them at all). A token is required on any bind address that
is not loopback, because a WebSocket reachable from the network lets anyone publish on the robot.
"""

from __future__ import annotations

import fnmatch
import hmac
import ipaddress
import re
from collections.abc import Sequence

from mrosd.errors import ConfigError

__all__ = ["DEFAULT_ASSETS", "AccessPolicy", "is_loopback"]

#: Asset URIs served by default: meshes, textures and robot descriptions of ROS packages, the files
#: foxglove_bridge's default ``asset_uri_allowlist`` names (upper-case suffixes too: CAD exporters write
#: ``.STL``). ``mrosd.web.assets`` refuses every other scheme and any ``..`` whatever the globs say.
_ASSET_SUFFIXES = ("dae", "fbx", "glb", "gltf", "jpeg", "jpg", "mtl", "obj", "png", "stl", "tif", "tiff", "urdf")
DEFAULT_ASSETS: tuple[str, ...] = tuple(
    f"package://*.{suffix}" for ext in (*_ASSET_SUFFIXES, "webp", "xacro") for suffix in (ext, ext.upper())
)


def is_loopback(host: str) -> bool:
    """True for ``127.0.0.0/8``, ``::1`` and ``localhost``; every other address is reachable from outside."""
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _compile(globs: Sequence[str]) -> re.Pattern[str] | None:
    if not globs:
        return None
    return re.compile("|".join(f"(?:{fnmatch.translate(g)})" for g in globs))


class AccessPolicy:
    """Allow-lists and the token; ``allows_*`` answer for one resolved name."""

    def __init__(
        self,
        *,
        topics: Sequence[str] = ("*",),
        services: Sequence[str] = ("*",),
        params: Sequence[str] = ("*",),
        token: str = "",
        assets: Sequence[str] = DEFAULT_ASSETS,
        hostnames: Sequence[str] = (),
        allowed_origins: Sequence[str] = (),
    ) -> None:
        self.topics = list(topics)
        self.assets = list(assets)
        self.services = list(services)
        self.params = list(params)
        self.token = token
        #: names the web ports answer to besides IP literals and localhost, and other pages allowed to
        #: connect (``mrosd.web.admission.OriginGate``)
        self.hostnames = list(hostnames)
        self.allowed_origins = list(allowed_origins)
        self._topics = _compile(topics)
        self._services = _compile(services)
        self._params = _compile(params)
        self._assets = _compile(assets)

    def check_bind(self, hosts: str | Sequence[str]) -> None:
        """Refuse to listen off-loopback without a token, on any one of ``hosts``.

        Raises:
            ConfigError: an address is reachable from the network and no token is set.
        """
        for host in [hosts] if isinstance(hosts, str) else hosts:
            if not is_loopback(host) and not self.token:
                raise ConfigError(f"web: binding {host!r} (not loopback) needs a token ([web] token)")

    def token_ok(self, offered: str | None) -> bool:
        """True when no token is configured or ``offered`` matches it (constant-time compare)."""
        if not self.token:
            return True
        return offered is not None and hmac.compare_digest(offered.encode(), self.token.encode())

    def allows_topic(self, name: str) -> bool:
        return self._topics is not None and self._topics.fullmatch(name) is not None

    def allows_service(self, name: str) -> bool:
        return self._services is not None and self._services.fullmatch(name) is not None

    def allows_param(self, name: str) -> bool:
        return self._params is not None and self._params.fullmatch(name) is not None

    def allows_asset(self, uri: str) -> bool:
        return self._assets is not None and self._assets.fullmatch(uri) is not None
