"""IXM access rules enforced between two real uids: a denied reader cannot read, a reader cannot write.

Needs root (to create a user and switch to it); skipped with a reason otherwise. The other user's process
is a fork of this one that drops to that uid (the project's interpreter lives under /root, which the user
cannot execute), then talks to a daemon that runs as root.
"""

from __future__ import annotations

import json
import mmap
import os
import pwd
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from mrosd.errors import IxmError, IxmPermissionError
from mrosd.ixm import IxmClient
from tests.integration.ixm.conftest import ShmGuard, start_daemon
from tests.rosenv import Processes

USER = "mrosdixmtest"

pytestmark = pytest.mark.root


@pytest.fixture
def other_user() -> Iterator[pwd.struct_passwd]:
    if os.geteuid() != 0:
        pytest.skip("needs root to create a second user and switch to it")
    if shutil.which("useradd") is None:
        pytest.skip("useradd is not installed")
    created = False
    try:
        pw = pwd.getpwnam(USER)
    except KeyError:
        subprocess.run(["useradd", "--no-create-home", "--shell", "/usr/sbin/nologin", USER], check=True, timeout=30)
        created = True
        pw = pwd.getpwnam(USER)
    try:
        yield pw
    finally:
        if created:
            subprocess.run(["userdel", USER], check=False, timeout=30)


def run_as(user: pwd.struct_passwd, fn: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """Run ``fn`` in a forked child that switched to ``user``; returns what it returned (as JSON).

    The child's every wait is bounded by the IXM client's own timeout, so the parent's read ends.
    """
    rfd, wfd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        code = 0
        try:
            os.close(rfd)
            os.setgroups([])
            os.setgid(user.pw_gid)
            os.setuid(user.pw_uid)
            result = fn()
        except BaseException as exc:
            result = {"crash": repr(exc)}
            code = 1
        os.write(wfd, json.dumps(result).encode())
        os._exit(code)
    os.close(wfd)
    chunks = []
    with os.fdopen(rfd, "rb") as r:
        chunks.append(r.read())
    _, status = os.waitpid(pid, 0)
    result: dict[str, Any] = json.loads(b"".join(chunks) or b"{}")
    assert "crash" not in result, result
    assert os.waitstatus_to_exitcode(status) == 0
    return result


def outcome(action: Callable[[], object]) -> str:
    try:
        value = action()
    except IxmPermissionError:
        return "denied"
    except IxmError as exc:
        return f"error: {exc}"
    except PermissionError:
        return "EACCES"
    except TypeError:
        return "read-only"
    return f"ok {value!r}"


def test_a_denied_reader_cannot_read_and_a_reader_cannot_write(
    other_user: pwd.struct_passwd, shm_guard: ShmGuard, procs: Processes
) -> None:
    with tempfile.TemporaryDirectory(prefix="mrosd-ixm-users-") as tmp:
        os.chmod(tmp, 0o755)  # the other user must reach the socket; the daemon's rules decide the rest
        config = Path(tmp) / "mrosd.toml"
        config.write_text(
            '[ixm.rules]\ndefault = "deny"\n'
            '[ixm.rules.keys."/secret"]\nread_uids = [0]\n'
            f'[ixm.rules.keys."/shared"]\nread_uids = [{other_user.pw_uid}]\n'
        )
        sock = shm_guard.watch(os.path.join(tmp, "ixm.sock"))
        daemon = start_daemon(procs, sock, str(config))
        with IxmClient(sock) as ixm:
            ixm.open("/secret", "float64", mode="w").write(42.0)
            writer = ixm.open("/shared", "float64", count=2, mode="w")
            writer.write([1.0, 2.0])

            def as_other() -> dict[str, Any]:
                with IxmClient(sock, name="intruder") as c:
                    shared = c.open("/shared", "float64", count=2)
                    fd = shared._state.fd
                    with IxmClient(sock) as c2:
                        write_open = outcome(lambda: c2.open("/shared", "float64", count=2, mode="w"))
                    return {
                        "secret": outcome(lambda: c.open("/secret", "float64")),
                        "shared_read": outcome(shared.read),
                        "shared_write_open": write_open,
                        "api_write": outcome(lambda: shared.write([9.0, 9.0])),
                        "mapping_write": outcome(lambda: shared._state.map.__setitem__(64, 1)),
                        "mmap_writable": outcome(
                            lambda: mmap.mmap(fd, 0, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
                        ),
                        "reopen_rw": outcome(lambda: os.open(f"/proc/self/fd/{fd}", os.O_RDWR)),
                        "unknown_key": outcome(lambda: c.open("/other", "float64", mode="w")),
                    }

            result = run_as(other_user, as_other)
            assert ixm.list("/shared").segments[0].shm_name.startswith("memfd:")
            daemon_fds = [f"/proc/{daemon.pid}/fd/{fd}" for fd in os.listdir(f"/proc/{daemon.pid}/fd")]
            segment_file = next(p for p in daemon_fds if os.readlink(p).startswith("/memfd:mrosd-ixm-"))

            def open_by_path() -> dict[str, Any]:
                return {"path": outcome(lambda: os.open(segment_file, os.O_RDWR))}

            by_path = run_as(other_user, open_by_path)
            with IxmClient(sock) as check:
                assert check.open("/shared").read() == [1.0, 2.0]
        assert result == {
            "secret": "denied",
            "shared_read": "ok [1.0, 2.0]",
            "shared_write_open": "denied",
            "api_write": "error: /shared is open for reading only (mode 'r')",
            "mapping_write": "read-only",
            "mmap_writable": "EACCES",
            "reopen_rw": "EACCES",
            "unknown_key": "denied",
        }
        assert by_path == {"path": "EACCES"}


def test_a_reader_of_another_uid_is_refused_write_access_on_open(
    other_user: pwd.struct_passwd, shm_guard: ShmGuard, procs: Processes
) -> None:
    with tempfile.TemporaryDirectory(prefix="mrosd-ixm-users-") as tmp:
        os.chmod(tmp, 0o755)
        sock = shm_guard.watch(os.path.join(tmp, "ixm.sock"))
        start_daemon(procs, sock)  # default policy: anyone reads, only the creator's uid writes
        with IxmClient(sock) as ixm:
            ixm.open("/cmd", "int32", mode="w").write(3)

            def as_other() -> dict[str, Any]:
                with IxmClient(sock) as c:
                    return {
                        "write": outcome(lambda: c.open("/cmd", "int32", mode="w")),
                        "read": outcome(lambda: c.open("/cmd", "int32").read()),
                    }

            assert run_as(other_user, as_other) == {"write": "denied", "read": "ok 3"}
