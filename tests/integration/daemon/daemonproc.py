"""A real ``mrosd`` subprocess watched the way systemd watches it: NOTIFY_SOCKET datagrams and stderr.

Shared by the daemon's integration tests and its hostile tests in ``tests/reliability``.
"""

from __future__ import annotations

import os
import signal
import socket
import time
from pathlib import Path

from tests.rosenv import Processes, free_port

_LOWER_NOFILE = (
    "import os, resource, sys; hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]; "
    "resource.setrlimit(resource.RLIMIT_NOFILE, (int(sys.argv[1]), hard)); "
    "os.execv(sys.executable, [sys.executable, *sys.argv[2:]])"
)


def daemon_env(tmp: Path, notify: str = "", **extra: str) -> dict[str, str]:
    """The environment of a test daemon: no inherited ROS_/MROSD_/systemd variables, journald-style logs."""
    drop = ("ROS_", "MROSD_", "NOTIFY_", "WATCHDOG_", "JOURNAL_")
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop)}
    env.update(
        JOURNAL_STREAM="8:12345",
        MROSD_IXM_SOCKET=str(tmp / "run" / "ixm.sock"),
        ROS_HOSTNAME="127.0.0.1",
        ROS_LOG_DIR=str(tmp / "ros_log"),
        PYTHONUNBUFFERED="1",
        MROSD_WEB_PORT="0",  # the web part on free ports: parallel daemons must not fight over 8765 and 9090
        MROSD_WEB_ROSBRIDGE_PORT="0",
    )
    if notify:
        env["NOTIFY_SOCKET"] = notify
    env.update(extra)
    return env


class NotifyListener:
    """The systemd end of ``$NOTIFY_SOCKET``: a bound AF_UNIX datagram socket and what it received."""

    def __init__(self, tmp: Path) -> None:
        self.path = str(tmp / "notify.sock")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.seen: list[str] = []

    def until(self, wanted: str, timeout: float) -> list[str]:
        """Datagrams until one holds the line ``wanted`` (``READY=1``) or a line starting with it (``STATUS=``)."""
        deadline = time.monotonic() + timeout
        got: list[str] = []
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"no {wanted} within {timeout} s; got {got}")
            self.sock.settimeout(remaining)
            msg = self.sock.recv(65536).decode()
            got.append(msg)
            self.seen.append(msg)
            if any(line == wanted or line.startswith(wanted) for line in msg.split("\n")):
                return got

    def close(self) -> None:
        self.sock.close()


class DaemonRun:
    """One ``python -m mrosd.daemon`` started under ``procs`` with a notify socket; ``stop()`` sends SIGTERM."""

    def __init__(
        self,
        procs: Processes,
        tmp: Path,
        *args: str,
        env: dict[str, str] | None = None,
        soft_nofile: int | None = None,
        code: str | None = None,
        port: int | None = None,
    ) -> None:
        self.tmp = tmp
        self.port = free_port() if port is None else port
        self.uri = f"http://127.0.0.1:{self.port}/"
        self.notify = NotifyListener(tmp)
        self.env = daemon_env(tmp, self.notify.path) if env is None else {**env, "NOTIFY_SOCKET": self.notify.path}
        # ``code`` runs instead of ``-m mrosd.daemon`` (a harness that wraps the daemon); it sees the arguments.
        argv = ["-m", "mrosd.daemon"] if code is None else ["-c", code]
        argv += ["--port", str(self.port), *args]
        if soft_nofile is not None:  # lower the soft fd limit, then exec the daemon in the same process
            argv = ["-c", _LOWER_NOFILE, str(soft_nofile), *argv]
        self.proc = procs.our_python(argv, self.env)
        self._stderr = ""

    @property
    def ixm_socket(self) -> str:
        return self.env["MROSD_IXM_SOCKET"]

    def ready(self, timeout: float = 30.0) -> str:
        """Wait for ``READY=1``; return the STATUS text sent with it."""
        got = self.notify.until("READY=1", timeout)
        for line in got[-1].split("\n"):
            if line.startswith("STATUS="):
                return line.removeprefix("STATUS=")
        return ""

    def signal(self, signum: signal.Signals) -> None:
        self.proc.send_signal(signum)

    def stop(self, timeout: float = 15.0) -> tuple[int, float]:
        """SIGTERM, then the exit code and the seconds it took."""
        start = time.monotonic()
        self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout)
        return code, time.monotonic() - start

    def stderr(self) -> str:
        """Everything the daemon logged (once it exited)."""
        if not self._stderr and self.proc.stderr is not None and self.proc.poll() is not None:
            self._stderr = self.proc.stderr.read().decode()
        return self._stderr

    def close(self) -> None:
        self.notify.close()
