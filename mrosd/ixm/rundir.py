"""The directory that holds the IXM socket: created private, and an existing one checked before it is trusted.

Whoever can create entries in the socket's directory can put their own socket there and impersonate the
daemon to every client, or stop it from starting. So the daemon refuses a directory that is a symlink,
not a directory, owned by a uid other than its own or root's, or writable by group or others; a missing
one is created mode 0700 (``mkdir`` does not follow a symlink planted at its path, and the result is
checked through a descriptor opened with ``O_NOFOLLOW``). A daemon serving other users needs a directory
they can traverse: give it one (systemd: ``RuntimeDirectory=mrosd``, mode 0755) rather than a shared one.

Clients look for the socket differently from the daemon (``find_ixm_socket``): the daemon picks
``/run/mrosd`` only when it can create its socket there, but a user's client need only reach the socket
the systemd unit's daemon created there, never write to the directory.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Mapping

from mrosd.errors import IxmError

__all__ = ["SYSTEM_SOCKET", "client_run_dirs", "find_ixm_socket", "prepare_socket_dir"]

#: The socket of the packaged systemd unit (``RuntimeDirectory=mrosd``, ``MROSD_IXM_SOCKET`` in
#: packaging/mrosd.service).
SYSTEM_SOCKET = "/run/mrosd/ixm.sock"


def find_ixm_socket(environ: Mapping[str, str] | None = None) -> str:
    """The IXM socket a client connects to, first match wins.

    ``$MROSD_IXM_SOCKET``; else the socket of the daemon this user would run (``default_ixm_socket``) when
    one is there; else the systemd unit's (``SYSTEM_SOCKET``) when it is there, although this user cannot
    write to its directory; else the user's own path, for the error message.
    """
    from mrosd.config import default_ixm_socket

    env = os.environ if environ is None else environ
    if env.get("MROSD_IXM_SOCKET"):
        return env["MROSD_IXM_SOCKET"]
    own = default_ixm_socket(env)
    if _is_socket(own):
        return own
    system = SYSTEM_SOCKET
    if _is_socket(system):
        return system
    return own


def client_run_dirs(environ: Mapping[str, str] | None = None) -> list[str]:
    """The runtime directories a client looks in for a daemon's files (its status file), in order."""
    from mrosd.config import default_ixm_socket

    return [
        os.path.dirname(find_ixm_socket(environ)),
        os.path.dirname(default_ixm_socket(environ)),
        os.path.dirname(SYSTEM_SOCKET),
    ]


def _is_socket(path: str) -> bool:
    try:
        return stat.S_ISSOCK(os.stat(path).st_mode)
    except OSError:
        return False


def prepare_socket_dir(directory: str, euid: int | None = None) -> None:
    """Create ``directory`` (0700) if missing, then check that only ``euid`` (or root) controls it.

    Raises:
        IxmError: the directory is unsafe; the one-line message names it and the fix.
    """
    uid = os.geteuid() if euid is None else euid
    parent = os.path.dirname(os.path.abspath(directory)) or "/"
    if not os.path.lexists(directory):
        with contextlib.suppress(FileExistsError):
            os.makedirs(parent, exist_ok=True)
            os.mkdir(directory, 0o700)
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        if os.path.islink(directory):
            raise IxmError(
                f"the IXM socket directory {directory} is a symlink (to {os.readlink(directory)}); "
                "remove it or choose another socket path"
            ) from exc
        raise IxmError(f"cannot use the IXM socket directory {directory}: {exc.strerror or exc}") from exc
    try:
        st = os.fstat(fd)
    finally:
        os.close(fd)
    if st.st_uid not in (uid, 0):
        raise IxmError(
            f"the IXM socket directory {directory} is owned by uid {st.st_uid}, not by uid {uid} or root: "
            f"another user could impersonate the daemon; remove it or run 'chown {uid} {directory}'"
        )
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise IxmError(
            f"the IXM socket directory {directory} is writable by group or others (mode {st.st_mode & 0o7777:04o}): "
            f"another user could replace the socket; run 'chmod go-w {directory}' or choose another socket path"
        )
