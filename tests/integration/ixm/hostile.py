"""Helpers for hostile IXM tests: a shared runtime directory, a forked child of another uid, daemon figures."""

from __future__ import annotations

import json
import os
import pwd
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest

from tests.rosenv import Processes, iter_lines_until

NOBODY = "nobody"


def nobody() -> pwd.struct_passwd:
    if os.geteuid() != 0:
        pytest.skip("needs root to act as a second user")
    try:
        return pwd.getpwnam(NOBODY)
    except KeyError:
        pytest.skip("no 'nobody' user on this machine")


@contextmanager
def shared_dir() -> Iterator[str]:
    """A root-owned 0755 directory: other users reach the socket in it, only root creates entries."""
    with tempfile.TemporaryDirectory(prefix="mrosd-ixm-hostile-") as tmp:
        os.chmod(tmp, 0o755)
        yield tmp


class Child:
    """A forked child running as another uid; ``result()`` waits (bounded) for what it returned as JSON."""

    def __init__(self, user: pwd.struct_passwd, fn: Callable[[Callable[[dict[str, Any]], None]], dict[str, Any]]):
        self._rfd, wfd = os.pipe()
        go_r, self._go_w = os.pipe()
        self.pid = os.fork()
        if self.pid == 0:  # child: never returns into pytest
            code = 0
            try:
                os.close(self._rfd)
                os.close(self._go_w)
                os.setgroups([])
                os.setgid(user.pw_gid)
                os.setuid(user.pw_uid)

                def report(progress: dict[str, Any]) -> None:
                    os.write(wfd, (json.dumps(progress) + "\n").encode())
                    os.read(go_r, 1)  # hold everything until the parent says go

                result = fn(report)
            except BaseException as exc:
                result = {"crash": repr(exc)}
                code = 1
            os.write(wfd, (json.dumps(result) + "\n").encode())
            os._exit(code)
        os.close(wfd)
        os.close(go_r)
        self._buf = b""

    def line(self, timeout: float = 60.0) -> dict[str, Any]:
        import select

        deadline = time.monotonic() + timeout
        while b"\n" not in self._buf:
            remaining = deadline - time.monotonic()
            assert remaining > 0, "the child did not report in time"
            ready, _, _ = select.select([self._rfd], [], [], remaining)
            if ready:
                chunk = os.read(self._rfd, 65536)
                assert chunk, "the child exited without reporting"
                self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        value: dict[str, Any] = json.loads(line)
        return value

    def go(self) -> None:
        os.write(self._go_w, b"g")

    def close(self) -> None:
        for fd in (self._rfd, self._go_w):
            try:
                os.close(fd)
            except OSError:
                pass
        try:
            os.kill(self.pid, 9)
        except ProcessLookupError:
            pass
        try:
            os.waitpid(self.pid, 0)
        except ChildProcessError:
            pass


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid`` so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def fd_count(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


#: Runs an IXM daemon with a low fd limit; server keyword arguments the installed IxmServer does not know
#: are dropped, so that the same test runs against a daemon without caps.
DAEMON = textwrap.dedent(
    """
    import asyncio, inspect, json, resource, sys
    from mrosd.ixm.server import IxmServer
    from mrosd.ixm.rules import parse_rules
    import logging
    logging.basicConfig(level="INFO", stream=sys.stderr)
    limit = int(sys.argv[2])
    resource.setrlimit(resource.RLIMIT_NOFILE, (limit, limit))
    kwargs = json.loads(sys.argv[3])
    known = inspect.signature(IxmServer).parameters
    kwargs = {k: v for k, v in kwargs.items() if k in known}
    async def main():
        server = IxmServer(sys.argv[1], parse_rules({"default": "allow"}), **kwargs)
        await server.start()
        print("ready", flush=True)
        await asyncio.Event().wait()
    asyncio.run(main())
    """
)


def start_limited_daemon(
    procs: Processes, socket_path: str, fd_limit: int, stderr_path: str, **kwargs: int
) -> subprocess.Popen[bytes]:
    with open(stderr_path, "wb") as err:
        proc = procs.start(
            [sys.executable, "-c", DAEMON, socket_path, str(fd_limit), json.dumps(kwargs)], stderr=err.fileno()
        )
    assert next(iter_lines_until(proc, 1, 20.0)) == "ready"
    return proc


def own_memfds(pid: int) -> int:
    """Segments (memfds) a process holds open."""
    count = 0
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            if os.readlink(f"/proc/{pid}/fd/{fd}").startswith("/memfd:"):
                count += 1
        except OSError:
            pass
    return count
