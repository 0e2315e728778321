"""The running daemon's status file: which parts run, where they listen, and which failed and why.

``mros web`` and ``mros daemon status`` must say what the daemon actually serves (a port chosen by the
kernel, a web part that could not bind), not what the shell's settings suggest. So the daemon writes
``mrosd-<master port>.json`` into its runtime directory (the directory of its IXM socket: ``/run/mrosd``
under systemd, ``$XDG_RUNTIME_DIR/mrosd`` or ``/tmp/mrosd-<uid>`` otherwise) when it is ready and after
each reload, and removes it when it stops. A client looks for the file of the master port it talks to
(``$ROS_MASTER_URI``) in the directories where it would find the IXM socket, and trusts it only while the
process that wrote it is alive.

The file is written whole (a temporary file renamed over it), mode 0644, and holds no secret: a web token
is only said to be required. Reading it is bounded (``MAX_STATUS_BYTES``) and typed (``DaemonStatus``);
a file that does not decode is as good as none.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from urllib.parse import urlsplit

import msgspec

__all__ = [
    "MAX_STATUS_BYTES",
    "ClientDrops",
    "DaemonStatus",
    "EncoderCounts",
    "WebStatus",
    "find_status",
    "remove_status",
    "status_path",
    "write_status",
]

#: A status file is a few hundred bytes; anything larger is not ours.
MAX_STATUS_BYTES = 64 * 1024


class ClientDrops(msgspec.Struct, kw_only=True):
    """What the daemon dropped for one web client (its link is slower than its topics), per topic."""

    #: the protocol and the client's address, e.g. ``Foxglove client 10.0.0.2``
    client: str
    #: topic -> messages dropped so far (the largest counts of the client's topics)
    dropped: dict[str, int] = {}


class EncoderCounts(msgspec.Struct, kw_only=True):
    """One ``T/compressed`` topic the web part encodes for browser clients (``mrosd.web.compressed``)."""

    topic: str
    encoded: int = 0
    #: raw frames replaced by a newer one before they were encoded
    dropped: int = 0
    #: frames that could not be encoded
    refused: int = 0
    #: mean encode time per frame, ms (None: none yet)
    encode_ms: float | None = None


class WebStatus(msgspec.Struct, kw_only=True):
    """The web part's addresses as it bound them, and what it dropped for slow clients."""

    page: str
    foxglove: list[str]
    rosbridge: list[str] = []
    #: clients must give a token (the token itself is never written here)
    token_required: bool = False
    #: clients for which messages were dropped (the most dropping ones, bounded: ``mrosd.web.server``)
    drops: list[ClientDrops] = []
    #: the ``T/compressed`` encoders that ran (the most encoding ones, bounded: ``mrosd.web.server``)
    encoders: list[EncoderCounts] = []


class DaemonStatus(msgspec.Struct, kw_only=True):
    """What one running daemon serves; a part that is None is off or failed (``failed`` says why)."""

    pid: int
    version: str
    master_uri: str
    #: ``running`` or ``degraded`` (a part failed to start)
    state: str
    ixm: str | None = None
    ixm_bridges: int = 0
    rosout: bool = False
    web: WebStatus | None = None
    fleet: str | None = None
    #: part name -> why it did not start
    failed: dict[str, str] = {}


_decoder = msgspec.json.Decoder(DaemonStatus)


def status_path(run_dir: str, master_port: int) -> str:
    """The status file of the daemon whose master listens on ``master_port``."""
    return os.path.join(run_dir, f"mrosd-{master_port}.json")


def write_status(path: str, status: DaemonStatus) -> None:
    """Replace the file at ``path`` with ``status`` in one rename (a reader never sees half of it).

    Raises:
        OSError: the directory is missing or not writable.
    """
    directory = os.path.dirname(path) or "."
    fd, tmp = tempfile.mkstemp(prefix=".mrosd-status-", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(msgspec.json.encode(status))
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def remove_status(path: str) -> None:
    """Remove the status file (the daemon stops); a missing one is fine."""
    with contextlib.suppress(OSError):
        os.unlink(path)


def _read(path: str) -> DaemonStatus | None:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as f:
        data = f.read(MAX_STATUS_BYTES + 1)
    if len(data) > MAX_STATUS_BYTES:
        return None
    try:
        return _decoder.decode(data)
    except msgspec.DecodeError:
        return None


def _alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's daemon (systemd's DynamicUser): alive
        return True
    return True


def find_status(master_uri: str, run_dirs: list[str]) -> DaemonStatus | None:
    """The status of the live daemon whose master listens on ``master_uri``'s port, from the first of
    ``run_dirs`` that holds one; None when no daemon on this host wrote one (a master that is not mrosd,
    another host, a daemon that stopped)."""
    try:
        port = urlsplit(master_uri).port
    except ValueError:
        return None
    if port is None:
        return None
    for run_dir in dict.fromkeys(run_dirs):  # each directory once, in order
        status = _read(status_path(run_dir, port))
        if status is not None and _alive(status.pid):
            return status
    return None
