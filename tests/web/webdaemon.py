"""A real ``mrosd`` daemon with its web part, for the web's hostile tests: its ports, its RSS, the master's
``getPid`` latency watched from a thread all along an attack, and a real /cmd_vel subscriber that counts.

The daemon's log goes to a file (a daemon that logs a traceback per hostile connection must not block on a
full pipe, and the test counts the lines).
"""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import TracebackType

from tests.integration.daemon.daemonproc import NotifyListener, daemon_env
from tests.reliability.floods import get_pid
from tests.rosenv import Processes, free_port

MiB = 1024 * 1024


class WebDaemon:
    """``python -m mrosd.daemon`` with the web part on free ports; ``env`` adds to the test environment."""

    def __init__(self, procs: Processes, tmp: Path, **env: str) -> None:
        self.procs = procs
        self.port = free_port()
        self.uri = f"http://127.0.0.1:{self.port}/"
        self.notify = NotifyListener(tmp)
        self.log_path = tmp / "daemon.log"
        self._log = self.log_path.open("wb")
        self.proc = procs.start(
            [sys.executable, "-m", "mrosd.daemon", "--port", str(self.port)],
            daemon_env(tmp, self.notify.path, **env),
            stdout=subprocess.DEVNULL,
            stderr=self._log.fileno(),
        )
        status = ""
        for msg in self.notify.until("READY=1", 30.0):
            status += msg
        fox = re.search(r"foxglove ws://127\.0\.0\.1:(\d+)/", status)
        ros = re.search(r"rosbridge ws://127\.0\.0\.1:(\d+)/", status)
        assert fox is not None and ros is not None, status
        self.foxglove_port = int(fox.group(1))
        self.rosbridge_port = int(ros.group(1))

    @property
    def foxglove_url(self) -> str:
        return f"ws://127.0.0.1:{self.foxglove_port}/"

    @property
    def rosbridge_url(self) -> str:
        return f"ws://127.0.0.1:{self.rosbridge_port}/"

    def rss(self, field: str = "VmRSS") -> int:
        """The daemon's resident set, bytes (``VmHWM``: its peak so far)."""
        text = Path(f"/proc/{self.proc.pid}/status").read_text()
        match = re.search(field + r":\s+(\d+) kB", text)
        assert match is not None
        return int(match.group(1)) * 1024

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def close(self) -> None:
        self.procs.stop(self.proc)
        self._log.close()
        self.notify.close()


class Watch:
    """From a thread, every ``period`` s until closed: the master's getPid latency and the daemon's RSS peak."""

    def __init__(self, daemon: WebDaemon, period: float = 0.05) -> None:
        self.daemon = daemon
        self.period = period
        self.rss0 = daemon.rss()
        self.peak_rss = self.rss0
        self.worst = 0.0
        self.failed = 0
        self.probes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Watch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)
        self.peak_rss = max(self.peak_rss, self.daemon.rss("VmHWM"))

    def _run(self) -> None:
        while not self._stop.is_set():
            code, took = get_pid(self.daemon.uri, 5.0)
            self.probes += 1
            self.worst = max(self.worst, took)
            if code != 1:
                self.failed += 1
            self.peak_rss = max(self.peak_rss, self.daemon.rss("VmHWM"))
            self._stop.wait(self.period)

    @property
    def growth(self) -> int:
        return self.peak_rss - self.rss0

    def __str__(self) -> str:
        return (
            f"getPid worst {self.worst * 1000:.0f} ms over {self.probes} probes ({self.failed} failed), "
            f"RSS +{self.growth / MiB:.0f} MiB"
        )


class CmdVelCounter:
    """A real mrosd subscriber of /cmd_vel (geometry_msgs/Twist) in a thread of its own; ``count`` so far.
    Several at once need a node ``name`` each."""

    def __init__(self, master_uri: str, topic: str = "/cmd_vel", name: str = "cmd_vel_counter") -> None:
        self.master_uri = master_uri
        self.topic = topic
        self.name = name
        self.count = 0
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._done: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    async def _main(self) -> None:
        import mrosd
        from mrosd.msg import get_message_class

        self._loop = asyncio.get_running_loop()
        self._done = asyncio.Event()
        try:
            async with mrosd.Node(self.name, master_uri=self.master_uri, argv=[], host="127.0.0.1") as node:
                await node.subscribe(self.topic, get_message_class("geometry_msgs/Twist"), self._got)
                self._ready.set()
                await self._done.wait()
        except BaseException as exc:
            self._error = exc
            self._ready.set()

    def _got(self, msg: object) -> None:
        self.count += 1

    def __enter__(self) -> CmdVelCounter:
        self._thread.start()
        assert self._ready.wait(20), "the /cmd_vel subscriber did not start"
        if self._error is not None:
            raise self._error
        return self

    def wait_for(self, count: int, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while self.count < count and time.monotonic() < deadline:
            time.sleep(0.02)
        return self.count >= count

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._loop is not None and self._done is not None:
            self._loop.call_soon_threadsafe(self._done.set)
        self._thread.join(10)
