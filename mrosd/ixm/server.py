"""The IXM daemon side (the paper's ixmcore): a Unix-socket server that owns every segment's lifetime.

This module owns the I/O around the pure ``Registry``: accepting clients (each a ``ClientSession``,
``mrosd.ixm.session``: who it is from the kernel, SO_PEERCRED and /proc, and its bounded outbox), creating
segments, handing them out as file descriptors (SCM_RIGHTS; read-only descriptors to readers, so that their
mappings cannot be written), and telling writers which reader wake-up pipes to write. It is not in the data
path: writes and reads go straight to shared memory, and wake-ups go straight from writer to reader.

Segments are sealed memfds: sized once, their header written with ``pwrite``, made 0600 (a reader's
read-only descriptor cannot be reopened read-write through /proc by another uid), then sealed against
shrinking, growing and further seals, before any client sees them. So a client cannot resize a segment
(no SIGBUS for anyone), they have no name anyone could squat, and the daemon never maps one. What the
daemon does write for a client (the count of wake-list pushes it sent, checked by writers after each
write) lives in a page of its own per writer connection, which that client maps read-only.

Lifetime rules: a client's keys are released when its socket closes, whatever the reason (close, exit,
crash, kill -9); the last release frees the segment (the kernel frees the memory when the last mapping
goes). Outgoing data to a client is bounded by ``MAX_OUTBOX``: a client that does not read its socket is
disconnected (and so loses its keys) rather than growing the daemon's memory. Every resource a client can
make the daemon hold is capped overall and per uid (``Limits``); the accept loop backs off when the process
runs out of descriptors and tells the refused client why, in one line.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import hashlib
import logging
import os
import resource
import socket
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mrosd.errors import IxmError, IxmPermissionError, MrosError, RemoteProtocolError
from mrosd.ixm.channel import is_wake_pipe
from mrosd.ixm.protocol import (
    Close,
    Error,
    Hello,
    List,
    Listing,
    Ok,
    Open,
    Opened,
    ProcessView,
    SegmentView,
    WakeList,
    decode_request,
    encode,
)
from mrosd.ixm.registry import CreateSegment, Effect, ReadersChanged, Registry, UnlinkSegment
from mrosd.ixm.resources import Limits, NoticePage, Segment, wake_slot_refusal
from mrosd.ixm.rules import AccessRules, Peer, parse_rules
from mrosd.ixm.rundir import prepare_socket_dir
from mrosd.ixm.session import ClientSession, close_fd, peer_of
from mrosd.lograte import RateLimitedLog

__all__ = ["SHM_PREFIX", "IxmServer", "Limits", "segment_prefix"]

log = logging.getLogger("mrosd.ixm")

#: Segments are memfds named ``<SHM_PREFIX><socket hash>-<n>`` (visible in /proc/PID/fd, never in /dev/shm).
SHM_PREFIX = "mrosd-ixm-"
_OUT_OF_FDS = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)
_BACKOFF_MIN, _BACKOFF_MAX = 0.02, 0.25


def segment_prefix(socket_path: str) -> str:
    """The memfd name prefix of every segment served on ``socket_path``."""
    digest = hashlib.blake2s(os.path.abspath(socket_path).encode(), digest_size=4).hexdigest()
    return f"{SHM_PREFIX}{digest}-"


class IxmServer:
    """The registry daemon: ``start()``/``aclose()``, ``reload_rules()``; an async context manager.

    The caps (``Limits``) default to a share of the process's descriptor limit at ``start()``; a value given
    here is used as it is. ``max_keys*`` count keys held (one per process and key).
    """

    def __init__(
        self,
        socket_path: str,
        rules: AccessRules | Mapping[str, Any] | None = None,
        *,
        max_clients: int | None = None,
        max_clients_per_uid: int | None = None,
        max_keys: int | None = None,
        max_keys_per_uid: int | None = None,
    ) -> None:
        self.socket_path = str(socket_path)
        self.prefix = segment_prefix(self.socket_path)
        self._given = {
            "max_clients": max_clients,
            "max_clients_per_uid": max_clients_per_uid,
            "max_keys": max_keys,
            "max_keys_per_uid": max_keys_per_uid,
        }
        self.limits = Limits.for_fd_limit(resource.getrlimit(resource.RLIMIT_NOFILE)[0], **self._given)
        self.registry = Registry(self._resolve_rules(rules), self._name_segment)
        self._counter = 0
        self._segments: dict[str, Segment] = {}
        self._clients: dict[int, ClientSession] = {}
        self._clients_by_uid: dict[int, int] = {}
        self._next_conn = 1
        self._listener: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._spare_fd: int | None = None
        self._backoff = _BACKOFF_MIN
        self._paused: asyncio.TimerHandle | None = None
        self._ratelog = RateLimitedLog(log)

    @staticmethod
    def _resolve_rules(rules: AccessRules | Mapping[str, Any] | None) -> AccessRules:
        parsed = rules if isinstance(rules, AccessRules) else parse_rules(rules)
        return parsed.with_superuser(os.geteuid())

    def _name_segment(self, key: str) -> str:
        self._counter += 1
        return f"memfd:{self.prefix}{self._counter}"

    # lifecycle -----------------------------------------------------------------------------------------

    async def start(self) -> None:
        """Check (or create) the socket's directory, bind the socket (mode 0666: the rules decide, not the file).

        Raises:
            IxmError: the directory is unsafe, or another daemon answers on the socket path.
            OSError: the socket cannot be bound.
        """
        self._loop = asyncio.get_running_loop()
        self.limits = Limits.for_fd_limit(resource.getrlimit(resource.RLIMIT_NOFILE)[0], **self._given)
        self.registry.max_keys = self.limits.max_keys
        self.registry.max_keys_per_uid = self.limits.max_keys_per_uid
        self._prepare_path()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(self.socket_path)
            os.chmod(self.socket_path, 0o666)
            sock.listen(128)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self._listener = sock
        self._spare_fd = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
        self._loop.add_reader(sock.fileno(), self._on_accept)
        log.debug("IXM limits: %s", self.limits)

    def _prepare_path(self) -> None:
        path = Path(self.socket_path)
        prepare_socket_dir(str(path.parent))
        if os.path.lexists(self.socket_path):
            if self._socket_is_live():
                raise IxmError(f"another IXM daemon is already serving {path}")
            os.unlink(self.socket_path)

    def _socket_is_live(self) -> bool:
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        probe.settimeout(1.0)
        try:
            probe.connect(self.socket_path)
        except OSError:
            return False
        finally:
            probe.close()
        return True

    async def aclose(self) -> None:
        """Disconnect every client, free every segment, remove the socket file."""
        loop = self._loop
        if self._paused is not None:
            self._paused.cancel()
            self._paused = None
        if self._listener is not None and loop is not None:
            loop.remove_reader(self._listener.fileno())
            self._listener.close()
            self._listener = None
            with contextlib.suppress(OSError):
                os.unlink(self.socket_path)
        if self._spare_fd is not None:
            close_fd(self._spare_fd)
            self._spare_fd = None
        for client in list(self._clients.values()):
            self._drop(client, "daemon shutting down", level=logging.DEBUG)
        for seg in list(self._segments.values()):
            seg.close()
        self._segments.clear()

    async def __aenter__(self) -> IxmServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    def reload_rules(self, rules: AccessRules | Mapping[str, Any] | None) -> None:
        """New access rules apply to later opens; keys already open stay open (as with open files)."""
        self.registry.rules = self._resolve_rules(rules)
        log.info("IXM access rules reloaded")

    # connections ---------------------------------------------------------------------------------------

    def _on_accept(self) -> None:
        assert self._listener is not None and self._loop is not None
        for _ in range(64):
            try:
                sock, _addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno in _OUT_OF_FDS:
                    self._out_of_fds(exc)
                else:
                    self._ratelog.warning("accept", "IXM accept failed: %s", exc)
                return
            self._backoff = _BACKOFF_MIN
            sock.setblocking(False)
            try:
                peer = peer_of(sock)
            except OSError as exc:
                self._ratelog.warning("peercred", "IXM: cannot read the peer's credentials, closing: %s", exc)
                sock.close()
                continue
            refusal = self._over_client_limits(peer)
            if refusal:
                self._ratelog.warning(f"clients-{peer.uid}", "IXM: refused uid %d: %s", peer.uid, refusal)
                self._refuse(sock, refusal)
                continue
            client = ClientSession(self._next_conn, sock, peer, self._loop, self._drop)
            self._next_conn += 1
            self._clients[client.id] = client
            self._clients_by_uid[peer.uid] = self._clients_by_uid.get(peer.uid, 0) + 1
            self.registry.connect(client.id, peer)
            self._loop.add_reader(sock.fileno(), self._on_readable, client)
            log.debug("IXM client %d connected: pid %d uid %d", client.id, peer.pid, peer.uid)

    def _over_client_limits(self, peer: Peer) -> str:
        lim = self.limits
        mine = self._clients_by_uid.get(peer.uid, 0)
        if mine >= lim.max_clients_per_uid:
            return f"uid {peer.uid} already has {mine} IXM connections, the per-user limit (max_clients_per_uid)"
        if len(self._clients) >= lim.max_clients:
            return f"the IXM daemon has {len(self._clients)} connections, its limit (max_clients); try again later"
        return ""

    @staticmethod
    def _refuse(sock: socket.socket, message: str) -> None:
        """Tell a connection we will not serve why (one frame, best effort), then close it."""
        with contextlib.suppress(OSError):
            sock.send(encode(Error("limit", message)))
        sock.close()

    def _out_of_fds(self, exc: OSError) -> None:
        """EMFILE and friends: refuse the waiting clients through the spare descriptor, pause accepting a while.

        The listener stays readable while connections wait, so accepting again at once would spin; each
        waiting client gets a one-line error instead of a timeout.
        """
        assert self._listener is not None and self._loop is not None
        self._ratelog.error(
            "emfile", "IXM: out of file descriptors (%s); refusing connections, next try in %.2f s", exc, self._backoff
        )
        if self._spare_fd is not None:
            os.close(self._spare_fd)
            self._spare_fd = None
            for _ in range(256):
                try:
                    sock, _ = self._listener.accept()
                except OSError:
                    break
                self._refuse(sock, "the IXM daemon is out of file descriptors; try again later")
            with contextlib.suppress(OSError):
                self._spare_fd = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
        self._loop.remove_reader(self._listener.fileno())
        self._paused = self._loop.call_later(self._backoff, self._resume_accept)
        self._backoff = min(_BACKOFF_MAX, self._backoff * 2)

    def _resume_accept(self) -> None:
        self._paused = None
        if self._listener is None or self._loop is None:
            return
        if self._spare_fd is None:
            with contextlib.suppress(OSError):
                self._spare_fd = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
        self._loop.add_reader(self._listener.fileno(), self._on_accept)

    def _on_readable(self, client: ClientSession) -> None:
        try:
            if not client.reader.recv():
                self._drop(client, "closed its connection", level=logging.DEBUG)
                return
            while not client.closed:
                body = client.reader.next_frame()
                if body is None:
                    break
                self._handle(client, decode_request(body))
        except (BlockingIOError, InterruptedError):
            return
        except RemoteProtocolError as exc:
            self._drop(client, f"protocol error: {exc}", level=logging.WARNING)
        except OSError as exc:
            self._drop(client, f"socket error: {exc}", level=logging.DEBUG)
        except Exception:  # a bug of ours must cost this client its connection, never the daemon its life
            log.exception("IXM: internal error while serving client %d (pid %d)", client.id, client.peer.pid)
            self._drop(client, "dropped after an internal error", level=logging.ERROR)

    def _drop(self, client: ClientSession, reason: str, level: int) -> None:
        if client.closed:
            return
        client.closed = True
        if level >= logging.WARNING:
            self._ratelog.log(
                level,
                f"drop-{client.peer.uid}",
                "IXM client %d (pid %d, uid %d) %s",
                client.id,
                client.peer.pid,
                client.peer.uid,
                reason,
            )
        else:
            log.log(level, "IXM client %d (pid %d, uid %d) %s", client.id, client.peer.pid, client.peer.uid, reason)
        client.close()
        del self._clients[client.id]
        left = self._clients_by_uid.get(client.peer.uid, 1) - 1
        if left > 0:
            self._clients_by_uid[client.peer.uid] = left
        else:
            self._clients_by_uid.pop(client.peer.uid, None)
        self._apply(self.registry.disconnect(client.id), client.id)

    # requests ------------------------------------------------------------------------------------------

    def _handle(self, client: ClientSession, request: Any) -> None:
        match request:
            case Open():
                self._open(client, request)
            case Close(key=key):
                try:
                    effects = self.registry.close(client.id, key)
                except IxmError as exc:
                    client.send(Error("invalid", str(exc)))
                    return
                self._apply(effects, client.id)  # unlinked before the client hears Ok
                client.send(Ok())
            case List(key=key):
                client.send(self._listing(key, client.peer))
            case Hello(name=name):
                self.registry.rename(client.id, name)
                client.send(Ok())
            case _:  # pragma: no cover - the decoder only yields the types above
                raise RemoteProtocolError(f"unexpected request {type(request).__name__}")

    def _open(self, client: ClientSession, req: Open) -> None:
        wake_fd = client.reader.take_fds(1)[0] if req.wake else None
        try:
            if wake_fd is not None:
                if not is_wake_pipe(wake_fd):
                    raise IxmError(
                        "the wake-up descriptor sent with open is not the write end of a pipe "
                        "(a client older than this daemon sends an eventfd: upgrade it)"
                    )
                # writers write it with RWF_NOWAIT, whatever its flags; this covers kernels without that
                flags = fcntl.fcntl(wake_fd, fcntl.F_GETFL)
                fcntl.fcntl(wake_fd, fcntl.F_SETFL, flags | os.O_NONBLOCK)
                if "r" not in req.mode:
                    raise IxmError("a wake-up pipe only makes sense when opening for reading")
                self._check_wake_slots(req.key, client.peer.uid)
            info, effects = self.registry.open(client.id, req.key, req.type, req.count, req.max_size, req.mode)
        except IxmPermissionError as exc:
            close_fd(wake_fd)
            self._ratelog.log(  # a client can ask again and again: one line per uid and 10 s, with a count
                logging.INFO,
                f"refused-{client.peer.uid}",
                "IXM: refused %s of %s to pid %d uid %d",
                req.mode,
                req.key,
                client.peer.pid,
                client.peer.uid,
            )
            client.send(Error("permission", str(exc)))
            return
        except MrosError as exc:
            close_fd(wake_fd)
            client.send(Error("invalid", str(exc)))
            return
        notice: NoticePage | None = None
        fds: list[int] = []
        try:
            for effect in effects:
                if isinstance(effect, CreateSegment):
                    self._segments[effect.segment.key] = Segment(effect.segment)
            seg = self._segments[req.key]
            fds = [seg.open_fd(write="w" in req.mode)]
            if "w" in req.mode:
                fds.append(seg.open_lock())
                if client.notice is None:
                    notice = client.notice = NoticePage(f"mrosd-ixm-notice-{client.id}")
        except (OSError, MrosError) as exc:
            for fd in (wake_fd, *fds):
                close_fd(fd)
            self._apply(self.registry.close(client.id, req.key), client.id)
            self._ratelog.warning("create", "IXM: cannot create the segment for %s: %s", req.key, exc)
            client.send(Error("invalid", f"cannot create shared memory for {req.key}: {exc}"))
            return
        if wake_fd is not None:
            seg.wake_fds[client.id] = wake_fd
        # writers learn of a new reader (list queued, their notice count raised) before the reader hears
        # Opened, so that every write that starts after the reader's open returns will wake it
        self._apply(effects, client.id)
        t = info.type
        wake = seg.fds_to_wake(client.id) if "w" in req.mode else []
        if notice is not None:
            fds.append(notice.client_fd)
        reply = Opened(
            key=req.key,
            type=t.name,
            count=t.count,
            max_size=t.max_size,
            capacity=t.capacity,
            mode=req.mode,
            shm_name=info.shm_name,
            wake=len(wake),
            generation=client.pushes,
            notice=notice is not None,
        )
        client.send(reply, fds=[*fds, *wake], close_after=fds)

    def _check_wake_slots(self, key: str, uid: int) -> None:
        """Raises: IxmError: ``key`` has no woken-reader slot left, or ``uid`` holds its share of them."""
        seg = self._segments.get(key)
        if seg is None:
            return
        holders = (c.peer.uid for conn in seg.wake_fds if (c := self._clients.get(conn)) is not None)
        refusal = wake_slot_refusal(key, holders, uid)
        if refusal:
            raise IxmError(refusal)

    def _apply(self, effects: list[Effect], origin: int) -> None:
        for effect in effects:
            match effect:
                case UnlinkSegment(key=key):
                    seg = self._segments.pop(key, None)
                    if seg is not None:
                        seg.close()
                case ReadersChanged(key=key):
                    seg = self._segments.get(key)
                    if seg is None:
                        continue
                    for conn in list(seg.wake_fds):
                        if conn not in seg.info.readers:
                            close_fd(seg.wake_fds.pop(conn))
                    for conn in sorted(seg.info.writers):
                        if conn == origin:  # an opening "rw" client gets its list with Opened
                            continue
                        writer = self._clients.get(conn)
                        if writer is not None:
                            self._send_wake_list(writer, seg)
                case CreateSegment():
                    pass

    def _send_wake_list(self, writer: ClientSession, seg: Segment) -> None:
        fds = seg.fds_to_wake(writer.id)
        writer.pushes += 1
        writer.send(WakeList(key=seg.info.key, generation=writer.pushes, count=len(fds)), fds=fds)
        # published after the list is queued: a writer that sees the new count finds the list in its socket
        if writer.notice is not None:
            writer.notice.count[0] = writer.pushes

    def _listing(self, key: str | None, caller: Peer) -> Listing:
        """What ``caller`` may see: the keys its rules let it open, and who holds them; root sees all."""
        registry = self.registry
        everything = caller.uid in registry.rules.superusers
        visible = {
            s.key
            for s in registry.segments.values()
            if (key is None or s.key == key) and (everything or registry.visible(caller, s))
        }
        pid_of = {c: p.peer.pid for c, p in registry.processes.items()}
        segments = [
            SegmentView(
                key=s.key,
                shm_name=s.shm_name,
                type=s.type.name,
                count=s.type.count,
                max_size=s.type.max_size,
                capacity=s.type.capacity,
                creator_uid=s.creator_uid,
                readers=sorted(pid_of[c] for c in s.readers if c in pid_of),
                writers=sorted(pid_of[c] for c in s.writers if c in pid_of),
            )
            for s in sorted(registry.segments.values(), key=lambda s: s.key)
            if s.key in visible
        ]
        processes = []
        for p in registry.processes.values():
            keys = {k: m for k, m in p.keys.items() if k in visible}
            own = key is None and (everything or p.peer.uid == caller.uid)
            if keys or own:
                processes.append(ProcessView(name=p.name, pid=p.peer.pid, uid=p.peer.uid, keys=keys))
        return Listing(processes=processes, segments=segments)
