"""The daemon's parts share RLIMIT_NOFILE by budget: floods of two parts at once leave another uid served.

Before the budgets, the master's cap (the limit minus 64) and IXM's share (3/4 of the limit) each fit the limit
alone but not together: at 512 descriptors one uid's IXM share plus 600 idle master connections took the daemon
to 512/512 and the next client was told the IXM daemon is out of file descriptors.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tests.integration.ixm.hostile import Child, fd_count, nobody, shared_dir
from tests.reliability.floods import get_pid
from tests.reliability.test_reliability_ixm_exhaustion import flood, normal_client_works
from tests.rosenv import Processes, free_port

pytestmark = pytest.mark.root

LIMIT = 512
IDLE_MASTER = 600


def _start_daemon(procs: Processes, path: str, port: int, log: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_", "NOTIFY_", "WATCHDOG_"))}
    env.update(MROSD_IXM_SOCKET=path, ROS_HOSTNAME="127.0.0.1", MROSD_MASTER_HOST="0.0.0.0")
    code = (
        f"import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_NOFILE, ({LIMIT}, {LIMIT})); "
        f"sys.argv = ['mrosd', '--port', '{port}']; runpy.run_module('mrosd.daemon', run_name='__main__')"
    )
    with open(log, "wb") as err:
        daemon = procs.start([sys.executable, "-c", code], env, stdout=subprocess.DEVNULL, stderr=err.fileno())
    deadline = time.monotonic() + 30
    while not os.path.exists(path) or get_pid(f"http://127.0.0.1:{port}/", 1.0)[0] != 1:
        assert daemon.poll() is None and time.monotonic() < deadline, log.read_text()[-2000:]
        time.sleep(0.1)
    return daemon


def idle_master_connections(port: int, count: int) -> Callable[[Callable[[dict[str, Any]], None]], dict[str, Any]]:
    """For ``Child``: ``count`` idle connections to the master, held by the attacking uid until told to go.

    They come from that uid (the master counts local peers by the uid owning their socket): root's own
    connections would spend root's share, which is the caps' intent, not the attack.
    """

    def run(report: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
        held: list[socket.socket] = []
        for _ in range(count):
            s = socket.socket()
            s.settimeout(1.0)
            try:
                s.connect(("127.0.0.1", port))
            except OSError:
                s.close()
                continue
            held.append(s)
        report({"held": len(held)})
        return {"held": len(held)}

    return run


def test_an_ixm_share_and_600_idle_master_connections_leave_another_uid_served(
    procs: Processes, tmp_path: Path
) -> None:
    user = nobody()
    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        port = free_port()
        log = tmp_path / "daemon.log"
        daemon = _start_daemon(procs, path, port, log)
        uri = f"http://127.0.0.1:{port}/"
        child = Child(user, flood(path, 600, 64))
        idler = Child(user, idle_master_connections(port, IDLE_MASTER))
        try:
            held = child.line()
            idle = idler.line()
            time.sleep(0.5)
            answers = [get_pid(uri, 3.0) for _ in range(8)]
            normal = normal_client_works(path)
            fds = fd_count(daemon.pid)
            child.go()
            child.line()
        finally:
            child.close()
            idler.close()
        print(f"ixm flood {held}; {idle['held']} idle master connections; getPid {answers}; fds {fds}/{LIMIT}")
        assert daemon.poll() is None, log.read_text()[-2000:]
        assert normal == "ok 1.5", normal
        assert all(code == 1 for code, _ in answers), answers
        assert max(t for _, t in answers) < 0.1, answers
        assert fds < LIMIT - 16, f"the daemon holds {fds} of {LIMIT} descriptors"
