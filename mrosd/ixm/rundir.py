"""The directory that holds the IXM socket: created private, and an existing one checked before it is trusted.

Whoever can create entries in the socket's directory can put their own socket there and impersonate the
daemon to every client, or stop it from starting. So the daemon refuses a directory that is a symlink,
not a directory, owned by a uid other than its own or root's, or writable by group or others; a missing
one is created mode 0700 (``mkdir`` does not follow a symlink planted at its path, and the result is
checked through a descriptor opened with ``O_NOFOLLOW``). A daemon serving other users needs a directory
they can traverse: give it one (systemd: ``RuntimeDirectory=mrosd``, mode 0755) rather than a shared one.
"""

from __future__ import annotations

import contextlib
import os
import stat

from mrosd.errors import IxmError

__all__ = ["prepare_socket_dir"]


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
