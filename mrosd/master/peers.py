"""Who is at the other end of a local TCP connection: the uid owning the peer's socket, from the kernel.

Every node on the master's own host connects from a loopback address (or the host's own address), so an
address says nothing about who is calling; the kernel knows which uid opened each socket. The peer's socket
is the one whose local address is the peer's ``(host, port)`` and whose remote address is ours. Two ways to
ask, both answered by the kernel's socket table, neither trusting anything the peer sends:

* ``sock_diag`` (netlink, ``NETLINK_SOCK_DIAG``): one exact query per socket, about 6 us (measured); used
  whenever the kernel offers it.
* ``/proc/net/tcp`` and ``tcp6``: every socket of the network namespace, one line each; the fallback. Only
  lines of sockets connected to our port are decoded, but the kernel still prints them all: with 38 000
  sockets on the build machine, reading took 70 ms and a full decode 480 ms. So a table is re-read on a
  miss only after ``PROC_REFRESH`` seconds and ten times as long as the last read took: a flood never buys
  one read per connection, and reading costs the loop at most a tenth of its time.

The message layouts and the table parser are pure functions (tested without sockets); ``PeerUids`` is the
thin I/O shell. Lookups are for connections still open: a peer that already closed has no socket to find
(``None``), and the caller treats it as unknown.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import struct
import sys
import time

log = logging.getLogger(__name__)

#: Seconds a parsed /proc/net/tcp table is reused before a miss may parse it again (fallback only).
PROC_REFRESH = 0.25

_NETLINK_SOCK_DIAG = 4
_SOCK_DIAG_BY_FAMILY = 20
_NLM_F_REQUEST = 1
_NLMSG_ERROR = 2
_NLMSG_HEADER = struct.Struct("=IHHII")
#: inet_diag_req_v2: family, protocol, ext, pad, states; then inet_diag_sockid (ports and addresses in
#: network order), interface, cookie (all ones: "any socket with this address pair").
_REQ_HEAD = struct.Struct("=BBBBI")
_SOCKID_PORTS = struct.Struct("!HH")
_REQ_TAIL = struct.Struct("=III")
_NO_COOKIE = 0xFFFFFFFF
#: inet_diag_msg: family, state, timer, retrans (4 bytes), sockid (48), expires, rqueue, wqueue (12), uid.
_MSG_UID_OFFSET = 4 + 48 + 12
_UID = struct.Struct("=I")

Endpoint = tuple[str, int]


def peer_address(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """A peer's address as the kernel gave it (``::ffff:a.b.c.d`` as IPv4, no ``%scope``); None if unparsable."""
    try:
        addr = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return None
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        return addr.ipv4_mapped
    return addr


def is_local(peer_host: str, our_host: str) -> bool:
    """Whether a connection comes from this host: a loopback peer, or one using our own address."""
    addr = peer_address(peer_host)
    return addr is not None and (addr.is_loopback or peer_host == our_host)


def _family(host: str) -> int:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def diag_request(peer: Endpoint, ours: Endpoint, seq: int = 1) -> bytes:
    """The netlink message asking for the TCP socket bound to ``peer`` and connected to ``ours``."""
    family = _family(peer[0])
    src = socket.inet_pton(family, peer[0].split("%", 1)[0]).ljust(16, b"\0")
    dst = socket.inet_pton(family, ours[0].split("%", 1)[0]).ljust(16, b"\0")
    body = (
        _REQ_HEAD.pack(family, socket.IPPROTO_TCP, 0, 0, 0xFFFFFFFF)
        + _SOCKID_PORTS.pack(peer[1], ours[1])
        + src
        + dst
        + _REQ_TAIL.pack(0, _NO_COOKIE, _NO_COOKIE)
    )
    return _NLMSG_HEADER.pack(_NLMSG_HEADER.size + len(body), _SOCK_DIAG_BY_FAMILY, _NLM_F_REQUEST, seq, 0) + body


def parse_diag_reply(data: bytes) -> int | None:
    """The uid in a ``sock_diag`` answer; None for an error (no such socket) or anything malformed."""
    if len(data) < _NLMSG_HEADER.size:
        return None
    length, kind, _flags, _seq, _pid = _NLMSG_HEADER.unpack_from(data)
    if kind != _SOCK_DIAG_BY_FAMILY or length > len(data):
        return None
    offset = _NLMSG_HEADER.size + _MSG_UID_OFFSET
    if length < offset + _UID.size:
        return None
    return int(_UID.unpack_from(data, offset)[0])


def _proc_address(text: str) -> str:
    """``0100007F`` -> ``127.0.0.1``: /proc prints each 32-bit word of an address in host byte order."""
    raw = bytes.fromhex(text)
    words = b"".join(
        raw[i : i + 4][::-1] if sys.byteorder == "little" else raw[i : i + 4] for i in range(0, len(raw), 4)
    )
    return str(ipaddress.ip_address(words))


def parse_proc_net_tcp(text: str, remote_port: int | None = None) -> dict[tuple[Endpoint, Endpoint], int]:
    """``/proc/net/tcp`` or ``tcp6`` -> ``{(local, remote): uid}``; lines that do not parse are skipped.

    ``remote_port``: keep only sockets connected to that port (a substring test skips the rest undecoded).
    """
    table: dict[tuple[Endpoint, Endpoint], int] = {}
    wanted = None if remote_port is None else f":{remote_port:04X} "
    for line in text.splitlines()[1:]:
        if wanted is not None and wanted not in line:
            continue
        fields = line.split()
        if len(fields) < 8:
            continue
        try:
            local_addr, local_port = fields[1].split(":")
            remote_addr, remote_hex = fields[2].split(":")
            local = (_proc_address(local_addr), int(local_port, 16))
            port = int(remote_hex, 16)
            if remote_port is not None and port != remote_port:
                continue
            table[(local, (_proc_address(remote_addr), port))] = int(fields[7])
        except ValueError:
            continue
    return table


def _canonical(host: str) -> str:
    """The address as ``ipaddress`` prints it (what ``parse_proc_net_tcp`` keys on)."""
    try:
        return str(ipaddress.ip_address(host.split("%", 1)[0]))
    except ValueError:
        return host


class PeerUids:
    """Looks up the uid owning the peer's end of local TCP connections (``sock_diag``, else /proc)."""

    def __init__(self) -> None:
        self._netlink: socket.socket | None = None
        self._netlink_failed = False
        self._seq = 0
        self._table: dict[tuple[Endpoint, Endpoint], int] = {}
        self._next_read = 0.0
        #: Full /proc parses so far (a flood must not make this grow per connection).
        self.table_parses = 0

    def uid(self, peer: Endpoint, ours: Endpoint) -> int | None:
        """The uid owning the socket at ``peer`` connected to ``ours``; None when it cannot be told."""
        if not self._netlink_failed:
            found = self._ask_kernel(peer, ours)
            if found is not None or not self._netlink_failed:
                return found
        key = ((_canonical(peer[0]), peer[1]), (_canonical(ours[0]), ours[1]))
        uid = self._table.get(key)
        if uid is None and time.monotonic() >= self._next_read:
            self._read_table(ours[1])
            uid = self._table.get(key)
        return uid

    def _ask_kernel(self, peer: Endpoint, ours: Endpoint) -> int | None:
        try:
            if self._netlink is None:
                self._netlink = socket.socket(socket.AF_NETLINK, socket.SOCK_DGRAM, _NETLINK_SOCK_DIAG)
                self._netlink.settimeout(0.1)
            self._seq = (self._seq + 1) & 0x7FFFFFFF
            self._netlink.send(diag_request(peer, ours, self._seq))
            while True:  # skip a late answer to an earlier query that timed out
                data = self._netlink.recv(8192)
                if len(data) < _NLMSG_HEADER.size or _NLMSG_HEADER.unpack_from(data)[3] == self._seq:
                    return parse_diag_reply(data)
        except (OSError, ValueError) as exc:
            if not self._netlink_failed:
                log.info("master: sock_diag unavailable (%s); telling local peers apart by /proc/net/tcp", exc)
            self._netlink_failed = True
            self.close()
            return None

    def _read_table(self, port: int) -> None:
        start = time.monotonic()
        table: dict[tuple[Endpoint, Endpoint], int] = {}
        for path in ("/proc/net/tcp", "/proc/net/tcp6"):
            try:
                with open(path, encoding="ascii", errors="replace") as f:
                    table.update(parse_proc_net_tcp(f.read(), port))
            except OSError:
                continue
        self._table = table
        now = time.monotonic()
        self._next_read = now + max(PROC_REFRESH, 10 * (now - start))
        self.table_parses += 1

    def close(self) -> None:
        if self._netlink is not None:
            self._netlink.close()
            self._netlink = None
