"""Who may open a WebSocket on the web ports, and what a connection holds before and after it authenticates.

Pure data, no sockets: ``OriginGate`` answers for one handshake's ``Host`` and ``Origin`` headers, and
``Admission`` counts the connections each remote address holds. The server (``mrosd.web.server``) asks them
and does what they return.

**Origin.** Browsers apply no same-origin rule to WebSockets: any page the operator opens can connect to
``ws://127.0.0.1:8765`` through the operator's own browser, and a browser always says which page asks in
``Origin``. So a handshake that carries an ``Origin`` is refused unless it is the page mrosd serves itself
(``http://<the name the socket is reached by>:<the Foxglove port>``) or is listed in ``[web] allowed_origins``.
A client without ``Origin`` is not a browser page (node, Python, Foxglove desktop): it is admitted.

**Host.** DNS rebinding makes an attacker's name resolve to the robot, so that their page becomes "same
origin" with it; the ``Host`` header then names the attacker's domain. A ``Host`` is accepted only when it is
an IP literal, ``localhost``, or one of ``[web] hostnames``.

**Admission.** A connection that has not authenticated yet (rosbridge's ``auth`` op) is *pending*: it holds
none of the ``max_clients`` slots, only a pending one, bounded per remote address and in all; when either
bound is reached the oldest pending connection of that address (or of all) is closed to make room, so
strangers can delay each other but never keep one who has the token out. Authenticated connections hold a
slot, bounded in all and per address.
"""

from __future__ import annotations

import collections
import ipaddress
import urllib.parse
from collections.abc import Hashable, Iterable

__all__ = ["Admission", "OriginGate", "host_name"]


def host_name(host: str) -> str:
    """The name part of a ``Host`` header or URL authority, lower-case, without port, brackets or final dot."""
    host = host.strip().lower()
    if host.startswith("["):
        end = host.find("]")
        return host[1:end] if end > 0 else host
    if host.count(":") == 1:
        host = host.rsplit(":", 1)[0]
    return host.rstrip(".")


def host_port(host: str) -> int | None:
    """The port of a ``Host`` header (None when it names none)."""
    host = host.strip()
    tail = host[host.find("]") + 1 :] if host.startswith("[") else host
    if tail.count(":") != 1:
        return None
    digits = tail.rsplit(":", 1)[1]
    return int(digits) if digits.isdigit() and len(digits) <= 5 else None


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class OriginGate:
    """The ``Host`` and ``Origin`` rules of the web ports.

    Args:
        hostnames: names (besides IP literals and ``localhost``) the ports may be reached by.
        allowed_origins: origins of other pages allowed to connect (``https://app.foxglove.dev``); ``*``
            allows every page on the web (not safe: see docs/web.md).
    """

    def __init__(self, hostnames: Iterable[str] = (), allowed_origins: Iterable[str] = ()) -> None:
        self.hostnames = frozenset(host_name(h) for h in hostnames if h.strip())
        origins = [o.strip().lower().rstrip("/") for o in allowed_origins if o.strip()]
        self.any_origin = "*" in origins
        self.allowed_origins = frozenset(o for o in origins if o != "*")

    def host_ok(self, host: str | None) -> bool:
        """A request's ``Host`` (None: none sent, as no browser does) is an address or a name we answer to."""
        if host is None:
            return True
        name = host_name(host)
        return _is_ip(name) or name == "localhost" or name in self.hostnames

    def refusal(self, host: str | None, origin: str | None, page_port: int) -> str | None:
        """Why a request is refused, or None when it may go on.

        ``page_port``: the Foxglove port, where the page is served (the page's own origin is on it).
        """
        if not self.host_ok(host):
            return (
                f"Host {host!r:.200} is not an address of this robot nor one of its names: add the name to "
                f"[web] hostnames to reach it by that name"
            )
        if origin is None or self.any_origin:
            return None
        if origin.strip().lower().rstrip("/") in self.allowed_origins:
            return None
        if host is not None and self._own_page(origin, host_name(host), page_port):
            return None
        # The socket's own origin (scheme://Host): what Python and node WebSocket clients (websocket-client,
        # ros-mcp's) send as Origin. A browser sends it only for a page that this very port served, and the
        # rosbridge port serves none; the Foxglove port serves ours.
        port = host_port(host) if host is not None else None
        if port is not None and self._own_page(origin, host_name(host or ""), port):
            return None
        return (
            f"Origin {origin!r:.200} is not this robot's page: a page from another site may not use the robot; "
            f"add it to [web] allowed_origins to allow it"
        )

    @staticmethod
    def _own_page(origin: str, host: str, page_port: int) -> bool:
        try:
            parsed = urllib.parse.urlsplit(origin.strip())
            port = parsed.port
        except ValueError:
            return False
        if parsed.scheme not in ("http", "https") or parsed.hostname is None:
            return False
        default = 443 if parsed.scheme == "https" else 80
        return parsed.hostname.rstrip(".").lower() == host and (port or default) == page_port


class Admission:
    """Slots of authenticated connections and of pending ones, per remote address and in all.

    ``admit``/``release`` count authenticated connections; ``pend``/``settle`` pending ones, keyed by any
    hashable the caller chooses (its connection), and ``pend`` returns the keys of the pending connections to
    close to make room for the new one.
    """

    def __init__(
        self,
        *,
        max_clients: int,
        per_address: int | None = None,
        max_pending: int = 256,
        pending_per_address: int = 32,
    ) -> None:
        self.max_clients = max_clients
        #: authenticated connections one address may hold (default: three quarters of all, at least one)
        self.per_address = per_address
        self.max_pending = max_pending
        self.pending_per_address = pending_per_address
        self.clients = 0
        self._by_address: collections.Counter[str] = collections.Counter()
        #: pending connection -> its address, oldest first
        self._pending: collections.OrderedDict[Hashable, str] = collections.OrderedDict()
        self._pending_by_address: collections.Counter[str] = collections.Counter()

    @property
    def address_cap(self) -> int:
        if self.per_address is not None:
            return self.per_address
        return max(1, self.max_clients * 3 // 4)

    def admit(self, address: str) -> str | None:
        """Take a slot for an authenticated connection from ``address``; why not, or None when taken."""
        if self.clients >= self.max_clients:
            return f"at most {self.max_clients} clients"
        if self._by_address[address] >= self.address_cap:
            return f"at most {self.address_cap} clients from one address"
        self.clients += 1
        self._by_address[address] += 1
        return None

    def release(self, address: str) -> None:
        self.clients -= 1
        self._by_address[address] -= 1
        if self._by_address[address] <= 0:
            del self._by_address[address]

    @property
    def pending(self) -> int:
        return len(self._pending)

    def pending_keys(self) -> list[Hashable]:
        return list(self._pending)

    def pend(self, key: Hashable, address: str) -> list[Hashable]:
        """Hold a pending slot for ``key``; the older pending connections to close for it (oldest first)."""
        evict: list[Hashable] = []
        if self._pending_by_address[address] >= self.pending_per_address:
            oldest = next(k for k, a in self._pending.items() if a == address)
            evict.append(oldest)
            self.settle(oldest)
        while len(self._pending) >= self.max_pending:
            oldest = next(iter(self._pending))
            evict.append(oldest)
            self.settle(oldest)
        self._pending[key] = address
        self._pending_by_address[address] += 1
        return evict

    def settle(self, key: Hashable) -> None:
        """``key`` is no longer pending (it authenticated, failed, or left); nothing when it was not."""
        address = self._pending.pop(key, None)
        if address is None:
            return
        self._pending_by_address[address] -= 1
        if self._pending_by_address[address] <= 0:
            del self._pending_by_address[address]
