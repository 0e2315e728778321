"""``mros web`` and ``mros daemon status`` report what the running daemon serves, not what the shell's
settings say it might.

Before: ``mros web`` computed the URL from the environment (it printed 8765, or 0 here, while the daemon
served another port), ``mros daemon status`` never mentioned the web part and exited 0 when it had failed,
and a master port in use was "Address already in use" with no port named.
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
from pathlib import Path

from tests.integration.daemon.daemonproc import DaemonRun, daemon_env
from tests.rosenv import PROJECT_ROOT, Processes


def mros(run: DaemonRun, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``mros ARGS`` with the daemon's environment (its master URI and IXM socket)."""
    full = {**(env or run.env), "ROS_MASTER_URI": run.uri, "PYTHONPATH": f"{PROJECT_ROOT}:{PROJECT_ROOT / 'cli'}"}
    full.pop("NOTIFY_SOCKET", None)
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", *args],
        env=full,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def served_port(status: str) -> int:
    """The Foxglove port in the daemon's STATUS line (``foxglove ws://127.0.0.1:PORT/``)."""
    found = re.search(r"foxglove ws://[^ ]*:(\d+)/", status)
    assert found, status
    return int(found.group(1))


def test_mros_web_prints_the_port_the_running_daemon_serves(procs: Processes, tmp_path: Path) -> None:
    run = DaemonRun(procs, tmp_path)  # the web part on a free port: the environment says 0
    try:
        port = served_port(run.ready())
        result = mros(run, "web")
        assert result.returncode == 0, result.stderr
        assert result.stdout.strip() == f"http://127.0.0.1:{port}/"
        assert result.stderr == ""
    finally:
        run.stop()
        run.close()


def test_daemon_status_lists_the_running_parts_and_their_addresses(procs: Processes, tmp_path: Path) -> None:
    run = DaemonRun(procs, tmp_path)
    try:
        port = served_port(run.ready())
        result = mros(run, "daemon", "status")
    finally:
        run.stop()
        run.close()
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert f"web: page http://127.0.0.1:{port}/" in out
    assert f"foxglove ws://127.0.0.1:{port}/" in out
    assert "rosbridge ws://127.0.0.1:" in out
    assert "rosout: running" in out
    assert f"ixm: listening at {run.ixm_socket}" in out


def test_daemon_status_reports_a_web_part_that_failed_and_exits_1(procs: Processes, tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, MROSD_WEB_PORT=str(port)))
        try:
            assert run.ready().startswith("degraded")
            status = mros(run, "daemon", "status")
            web = mros(run, "web")
        finally:
            run.stop()
            run.close()
    assert status.returncode == 1, status.stdout
    assert re.search(rf"web: failed to start: .*{port}.*in use", status.stdout, re.IGNORECASE), status.stdout
    assert web.returncode == 1
    assert "failed to start" in web.stderr and str(port) in web.stderr


def test_a_master_port_in_use_is_named_in_the_error(procs: Processes, tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("0.0.0.0", 0))
        busy.listen()
        port = busy.getsockname()[1]
        run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, MROSD_ROSOUT="0", MROSD_IXM="0"), port=port)
        assert run.proc.wait(timeout=30) == 1
    run.close()
    line = next(line for line in run.stderr().splitlines() if "cannot start" in line)
    assert f"port {port}" in line and "in use" in line, line
