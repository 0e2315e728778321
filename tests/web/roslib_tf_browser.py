"""tests/web/roslib_page.html's tf part (the real roslib: TFClient, ActionClient) in headless Chromium, driven
through tests/web/roslib_browser.mjs, synchronously: for module-scoped fixtures beside a daemon in a subprocess.

The page is served by ``python -m http.server`` from tests/web (the import map names ``/node_modules/...``).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from tests.rosenv import Processes, free_port, iter_lines_until

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))
HAVE_BROWSER_PACKAGES = all((HERE / "node_modules" / p).is_dir() for p in ("roslib", "playwright-core"))

needs_chromium = pytest.mark.skipif(
    NODE is None or not HAVE_BROWSER_PACKAGES or not CHROMIUM.exists(),
    reason="node, chromium or the npm packages are missing: scripts/install-system-deps.sh "
    "(nodejs, chromium, then `npm ci --prefix tests/web`)",
)


def page_server(procs: Processes) -> str:
    """Serve tests/web over HTTP on a free port; the page's origin (to allow on the daemon)."""
    port = free_port()
    procs.start(
        [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1", "--directory", str(HERE)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    origin = f"http://127.0.0.1:{port}"
    wait_for_page(origin)
    return origin


def wait_for_page(origin: str, timeout: float = 10.0) -> None:
    """``http.server`` answers (any HTTP answer will do)."""
    import urllib.error
    import urllib.request

    deadline = time.monotonic() + timeout
    while True:
        try:
            with urllib.request.urlopen(origin + "/roslib_page.html", timeout=1.0):
                return
        except (urllib.error.URLError, OSError):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


class Browser:
    """One Chromium with the page open and connected to ``rosbridge_url``; commands in, events out."""

    def __init__(self, procs: Processes, origin: str, rosbridge_url: str) -> None:
        assert NODE is not None
        self.procs = procs
        self.proc = procs.start(
            [NODE, str(HERE / "roslib_browser.mjs"), f"{origin}/roslib_page.html?part=tf", rosbridge_url],
            stdin=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        self.events: list[dict[str, Any]] = []
        self.until("subscribed", timeout=60)

    def send(self, **cmd: Any) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write((json.dumps(cmd) + "\n").encode())
        self.proc.stdin.flush()

    def until(self, event: str, timeout: float = 20.0, **match: Any) -> dict[str, Any]:
        """The next event ``event`` whose fields equal ``match``."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"no {event} {match} within {timeout} s; last events {self.events[-5:]}")
            for line in iter_lines_until(self.proc, 1, remaining):
                ev = json.loads(line)
                self.events.append(ev)
                if ev.get("event") == event and all(ev.get(k) == v for k, v in match.items()):
                    return ev

    def close(self) -> None:
        """Ask the driver to close Chromium (a signal would leave Chromium to the process-group kill)."""
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                self.send(cmd="close")
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(5.0)
        self.procs.stop(self.proc)


__all__ = ["Browser", "needs_chromium", "page_server"]
