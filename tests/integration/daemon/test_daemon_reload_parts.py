"""SIGHUP applies a changed ``[log]`` and ``[fleet]`` by restarting those parts; before, it only warned
"restart mrosd to apply it" and kept the old settings.

A real daemon subprocess, a real configuration file rewritten between signals, and the effects checked
where a user sees them: master.log moving to the new directory (same run id) with the graph's ``+PUB``
lines, the log level, and the fleet node appearing in and leaving the graph with its status service.
"""

from __future__ import annotations

import signal
import time
import xmlrpc.client
from pathlib import Path

import pytest

from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import Processes, free_port

FLEET_STATUS = "/mrosd_fleet/status"


def reload(run: DaemonRun) -> str:
    """SIGHUP, then the STATUS sent with the READY that ends the reload."""
    run.signal(signal.SIGHUP)
    run.notify.until("RELOADING=1", timeout=10)
    got = run.notify.until("READY=1", timeout=20)
    return next((line[7:] for line in got[-1].split("\n") if line.startswith("STATUS=")), "")


def services(uri: str) -> set[str]:
    with xmlrpc.client.ServerProxy(uri) as proxy:
        return {name for name, _ in proxy.getSystemState("/test")[2][2]}


def test_sighup_moves_the_log_files_and_sets_the_level(procs: Processes, tmp_path: Path) -> None:
    first, second = tmp_path / "logs1", tmp_path / "logs2"
    config = tmp_path / "mrosd.toml"
    config.write_text(f'[log]\nlevel = "info"\ndir = "{first}"\n[web]\nenabled = false\n')
    run = DaemonRun(procs, tmp_path, "--config", str(config))
    try:
        run.ready()
        (run_dir,) = [p for p in first.iterdir() if p.is_dir() and not p.is_symlink()]
        config.write_text(f'[log]\nlevel = "debug"\ndir = "{second}"\n[web]\nenabled = false\n')
        reload(run)
        with xmlrpc.client.ServerProxy(run.uri) as proxy:
            proxy.registerPublisher("/late", "/after_reload", "std_msgs/String", "http://127.0.0.1:1/")
        moved = second / run_dir.name / "master.log"
        deadline = time.monotonic() + 10
        while "+PUB [/after_reload]" not in (moved.read_text() if moved.exists() else ""):
            assert time.monotonic() < deadline, "master.log in the new directory has no +PUB line"
            time.sleep(0.05)
        assert (second / "latest").resolve() == second / run_dir.name
        assert (second / run_dir.name / "rosout.log").exists()  # rosout restarted into the new directory
        assert run.stop()[0] == 0
    finally:
        run.close()
    log = run.stderr()
    assert "restart mrosd" not in log
    assert "SIGHUP: [log] applied" in log
    assert "<7>" in log  # DEBUG lines once the level is debug


def test_sighup_starts_changes_and_stops_the_fleet_part(procs: Processes, tmp_path: Path) -> None:
    pytest.importorskip("zenoh", reason="the fleet part needs eclipse-zenoh (pip install 'mrosd[fleet]')")
    config = tmp_path / "mrosd.toml"
    base = "[ixm]\nenabled = false\n[rosout]\nenabled = false\n[web]\nenabled = false\n"

    def fleet(robot: str) -> str:
        return f'[fleet]\nenabled = true\nrobot = "{robot}"\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'

    config.write_text(base)
    run = DaemonRun(procs, tmp_path, "--config", str(config))
    try:
        assert "fleet" not in run.ready()
        config.write_text(base + fleet("robot1"))
        assert "fleet robot1" in reload(run)
        assert FLEET_STATUS in services(run.uri)
        config.write_text(base + fleet("robot2").replace('"tcp/', '"nonsense/'))
        assert "fleet robot1" in reload(run)  # a [fleet] that does not parse: the running part stays
        assert FLEET_STATUS in services(run.uri)
        config.write_text(base + fleet("robot2"))
        assert "fleet robot2" in reload(run)
        assert FLEET_STATUS in services(run.uri)
        config.write_text(base)
        status = reload(run)
        assert "fleet" not in status, status
        assert FLEET_STATUS not in services(run.uri)
        assert run.stop()[0] == 0
    finally:
        run.close()
    log = run.stderr()
    assert "restart mrosd" not in log
    assert "reload failed, keeping the running configuration: " in log and "fleet.listen" in log
