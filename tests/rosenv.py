"""Helpers shared by integration and interop tests: free ports, process lifetime, real ROS from Debian.

Every process started through ``Processes`` is killed when the fixture ends, whatever the test did.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

#: Debian's ROS tools run under the system interpreter, not the project's (pyenv/venv) python.
ROS_PYTHON = "/usr/bin/python3"
PROJECT_ROOT = Path(__file__).resolve().parent.parent


def ros_available() -> bool:
    """True when Debian's ros_comm (rosmaster, rospy, rostopic) is installed."""
    if shutil.which("rosmaster") is None or not Path(ROS_PYTHON).exists():
        return False
    probe = subprocess.run(
        [ROS_PYTHON, "-c", "import rospy, rostopic, rosgraph, genpy, std_msgs.msg"],
        capture_output=True,
        timeout=60,
        check=False,
    )
    return probe.returncode == 0


_ROS = ros_available()
needs_ros = pytest.mark.skipif(
    not _ROS, reason="Debian ROS 1 (ros_comm) is not installed: run scripts/install-system-deps.sh"
)


def free_port() -> int:
    """A TCP port that was free a moment ago on 127.0.0.1 (for tools that cannot bind port 0)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ros_env(master_uri: str, tmp: Path, **extra: str) -> dict[str, str]:
    """Environment for a real ROS process talking to ``master_uri`` on loopback."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "PYTHON"))}
    env.update(
        ROS_MASTER_URI=master_uri,
        ROS_HOSTNAME="127.0.0.1",
        ROS_HOME=str(tmp / "ros_home"),
        ROS_LOG_DIR=str(tmp / "ros_log"),
        PATH="/usr/bin:/bin:" + env.get("PATH", ""),
        PYTHONUNBUFFERED="1",
    )
    env.update(extra)
    return env


def wait_for_xmlrpc(uri: str, timeout: float = 20.0) -> None:
    """Block until an XML-RPC server at ``uri`` answers getPid (master or slave)."""
    deadline = time.monotonic() + timeout
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            with xmlrpc.client.ServerProxy(uri) as proxy:  # closed at once: no ResourceWarning under -W error
                proxy.getPid("/test")
            return
        except (OSError, xmlrpc.client.Error) as exc:
            last = exc
            time.sleep(0.05)
    raise TimeoutError(f"{uri} did not answer within {timeout} s: {last}")


class Processes:
    """Starts subprocesses in their own process group and kills every one of them at teardown."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self._procs: list[subprocess.Popen[bytes]] = []

    def start(
        self,
        argv: Sequence[str],
        env: dict[str, str] | None = None,
        *,
        stdout: int | None = subprocess.PIPE,
        stderr: int | None = subprocess.PIPE,
        stdin: int | None = subprocess.DEVNULL,
    ) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(list(argv), env=env, stdout=stdout, stderr=stderr, stdin=stdin, start_new_session=True)
        self._procs.append(proc)
        return proc

    def python(self, code: str, env: dict[str, str], **kw: int | None) -> subprocess.Popen[bytes]:
        """Run ``code`` under the system python that has rospy."""
        return self.start([ROS_PYTHON, "-c", code], env, **kw)  # type: ignore[arg-type]

    def our_python(
        self, argv: Sequence[str], env: dict[str, str] | None = None, **kw: int | None
    ) -> subprocess.Popen[bytes]:
        """Run a module or script under the project's own interpreter."""
        return self.start([sys.executable, *argv], env, **kw)  # type: ignore[arg-type]

    @staticmethod
    def stop(proc: subprocess.Popen[bytes], timeout: float = 5.0) -> None:
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(timeout)
        for stream in (proc.stdout, proc.stderr, proc.stdin):
            if stream is not None:
                stream.close()

    def close(self) -> None:
        for proc in reversed(self._procs):
            self.stop(proc)
        self._procs.clear()


def start_rosmaster(procs: Processes) -> str:
    """Start Debian's ``rosmaster --core`` on a free port; return its URI once it answers."""
    port = free_port()
    start_rosmaster_on(procs, port)
    return f"http://127.0.0.1:{port}/"


def start_rosmaster_on(procs: Processes, port: int) -> subprocess.Popen[bytes]:
    """Start Debian's ``rosmaster --core`` on ``port`` (tests that restart it on the same port); once it answers."""
    uri = f"http://127.0.0.1:{port}/"
    env = ros_env(uri, procs.tmp)
    proc = procs.start(
        ["rosmaster", "--core", "-p", str(port)], env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    wait_for_xmlrpc(uri)
    return proc


def iter_lines_until(proc: subprocess.Popen[bytes], count: int, timeout: float) -> Iterator[str]:
    """Yield up to ``count`` stdout lines of ``proc``, failing the test if they do not come in time.

    Reads the pipe's fd directly and keeps what follows the last yielded line on ``proc`` for the next call:
    a buffered ``readline`` after ``select`` would strand lines that arrived in one write inside Python's
    buffer, where ``select`` cannot see them. Do not mix with ``proc.stdout.readline()`` on the same process.
    """
    import selectors

    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    pending: bytearray = proc.__dict__.setdefault("_pending_stdout", bytearray())
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    got = 0
    try:
        while got < count:
            end = pending.find(b"\n")
            if end < 0:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not sel.select(remaining):
                    raise TimeoutError(f"only {got} of {count} lines within {timeout} s")
                chunk = os.read(fd, 65536)
                if not chunk:
                    if pending:  # a last line without its newline
                        line, pending[:] = bytes(pending), b""
                        got += 1
                        yield line.decode(errors="replace")
                        continue
                    raise EOFError(f"process ended after {got} of {count} lines")
                pending += chunk
                continue
            line = bytes(pending[:end])
            del pending[: end + 1]
            got += 1
            yield line.decode(errors="replace")
    finally:
        sel.close()
