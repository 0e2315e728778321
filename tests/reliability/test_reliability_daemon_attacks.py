"""The daemon process attacked as a whole: fd limits, a part that cannot start, a poisoned reload, a blocked loop.

Each test runs a real ``mrosd`` subprocess and watches it as systemd does (NOTIFY_SOCKET, stderr, exit code).
"""

from __future__ import annotations

import os
import resource
import shutil
import signal
import socket
import time
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path

import pytest

from mrosd.daemon import HARD_STOP_GRACE, SHUTDOWN_TIMEOUT
from mrosd.ixm.client import IxmClient
from tests.integration.daemon.daemonproc import DaemonRun, daemon_env
from tests.rosenv import Processes

DEEP_TOML = "a = " + "[" * 5000 + "]" * 5000 + "\n"


@pytest.fixture
def runs() -> Iterator[list[DaemonRun]]:
    made: list[DaemonRun] = []
    yield made
    for run in made:
        run.close()


def _getpid(uri: str, timeout: float = 5.0) -> int:
    with xmlrpc.client.ServerProxy(uri) as proxy:
        socket.setdefaulttimeout(timeout)
        try:
            code, _, pid = proxy.getPid("/attacker")
        finally:
            socket.setdefaulttimeout(None)
    assert code == 1
    return int(pid)


def _soft_nofile(pid: int) -> int:
    for line in Path(f"/proc/{pid}/limits").read_text().splitlines():
        if line.startswith("Max open files"):
            return int(line.split()[3])
    raise AssertionError("no 'Max open files' in /proc/PID/limits")


def test_the_soft_fd_limit_is_raised_to_the_hard_limit_at_start(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    if hard != resource.RLIM_INFINITY and hard <= 256:
        pytest.skip(f"the hard fd limit here ({hard}) leaves nothing to raise")
    run = DaemonRun(procs, tmp_path, soft_nofile=256)
    runs.append(run)
    run.ready()
    raised = _soft_nofile(run.proc.pid)
    assert raised > 256
    if hard != resource.RLIM_INFINITY:
        assert raised == hard
    assert run.stop()[0] == 0
    assert f"open files: {raised}" in run.stderr()


def test_sighup_with_a_toml_nested_5000_deep_keeps_the_rules_and_sigterm_still_cleans_up(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    config = tmp_path / "mrosd.toml"
    config.write_text('[ixm.rules]\ndefault = "creator"\n[rosout]\nenabled = false\n')
    run = DaemonRun(procs, tmp_path, "--config", str(config))
    runs.append(run)
    run.ready()
    with IxmClient(run.ixm_socket, name="holder") as client:
        key = client.open("/kept", "int64", mode="rw")
        key.write(7)

        config.write_text(DEEP_TOML)
        run.signal(signal.SIGHUP)
        run.notify.until("RELOADING=1", 10)
        run.notify.until("READY=1", 10)  # the reloader survived and said so

        config.write_text('[ixm.rules]\ndefault = "allow"\n[rosout]\nenabled = false\n')
        run.signal(signal.SIGHUP)
        run.notify.until("RELOADING=1", 10)
        run.notify.until("READY=1", 10)
        assert key.read() == 7
        key.close()
    code, _ = run.stop()
    log = run.stderr()
    assert code == 0, log
    assert "reload failed, keeping the running configuration" in log
    assert "nested" in log
    assert "IXM access rules reloaded" in log
    assert "Traceback" not in log
    assert not os.path.exists(run.ixm_socket), "the IXM socket was left behind"


def _assert_degraded(run: DaemonRun, part: str) -> str:
    status = run.ready()
    assert "degraded" in status and part in status, status
    assert _getpid(run.uri) == run.proc.pid  # the master answers
    return status


def test_an_ixm_socket_directory_that_cannot_be_created_leaves_the_master_running_degraded_until_repaired(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    env = daemon_env(tmp_path, MROSD_IXM_SOCKET=str(blocker / "ixm.sock"), MROSD_ROSOUT="0")
    run = DaemonRun(procs, tmp_path, env=env)
    runs.append(run)
    _assert_degraded(run, "ixm")
    with xmlrpc.client.ServerProxy(run.uri) as proxy:
        assert proxy.setParam("/kept", "/robot", "r2")[0] == 1

    blocker.unlink()  # the operator fixes the cause and reloads: IXM starts, the master never went away
    blocker.mkdir(mode=0o700)
    run.signal(signal.SIGHUP)
    run.notify.until("RELOADING=1", 10)
    status = run.ready(10)
    assert status.startswith("running:") and "ixm" in status, status
    with IxmClient(run.ixm_socket, name="after-repair") as client:
        client.open("/fixed", "int64", mode="rw").close()
    with xmlrpc.client.ServerProxy(run.uri) as proxy:
        assert proxy.getParam("/kept", "/robot") == [1, "Parameter [/robot]", "r2"]

    code, _ = run.stop()
    log = run.stderr()
    assert code == 0, log
    failed = [line for line in log.splitlines() if "did not start" in line]
    assert len(failed) == 1, log
    assert failed[0].startswith("<3>") and "ixm" in failed[0] and str(blocker) in failed[0]
    assert "Traceback" not in log


def test_strict_makes_a_part_that_cannot_start_fatal(procs: Processes, tmp_path: Path, runs: list[DaemonRun]) -> None:
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    env = daemon_env(tmp_path, MROSD_IXM_SOCKET=str(blocker / "ixm.sock"), MROSD_ROSOUT="0")
    run = DaemonRun(procs, tmp_path, "--strict", env=env)
    runs.append(run)
    assert run.proc.wait(30) == 1
    log = run.stderr()
    assert "cannot start" in log and "ixm" in log and str(blocker) in log
    assert "Traceback" not in log


@pytest.mark.root
@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to hand a directory to another user (chown nobody)")
def test_an_ixm_socket_directory_owned_by_another_user_is_refused_and_the_master_keeps_running(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    foreign = tmp_path / "foreign"
    foreign.mkdir(mode=0o755)
    shutil.chown(foreign, "nobody")
    env = daemon_env(tmp_path, MROSD_IXM_SOCKET=str(foreign / "ixm.sock"), MROSD_ROSOUT="0")
    run = DaemonRun(procs, tmp_path, env=env)
    runs.append(run)
    _assert_degraded(run, "ixm")
    assert not (foreign / "ixm.sock").exists()
    code, _ = run.stop()
    log = run.stderr()
    assert code == 0, log
    failed = [line for line in log.splitlines() if "did not start" in line]
    assert len(failed) == 1 and "ixm" in failed[0] and str(foreign) in failed[0], log


def _big_call(size: int) -> bytes:
    """A setParam whose body is ``size`` bytes of small array elements: the slowest XML-RPC to parse per byte."""
    head = b"<?xml version='1.0'?><methodCall><methodName>setParam</methodName><params>"
    head += b"<param><value>/attacker</value></param><param><value>/big</value></param><param><value><array><data>"
    tail = b"</data></array></value></param></params></methodCall>"
    item = b"<value><struct></struct></value>"
    return head + item * ((size - len(head) - len(tail)) // len(item)) + tail


def test_sigterm_while_the_master_parses_big_bodies_exits_within_the_shutdown_bound_and_cleans_up(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    """Four 60 MiB bodies completed at once: parsed one after the other on the loop, ~25 s before SIGTERM is seen."""
    run = DaemonRun(procs, tmp_path, "--log-level", "warning")
    runs.append(run)
    run.ready()
    body = _big_call(60 << 20)
    request = b"POST / HTTP/1.1\r\nHost: x\r\nContent-Type: text/xml\r\nContent-Length: %d\r\n\r\n" % len(body)
    conns = [socket.create_connection(("127.0.0.1", run.port), timeout=30) for _ in range(4)]
    try:
        for conn in conns:
            conn.sendall(request + body[:-1])
        for conn in conns:
            conn.sendall(body[-1:])
        code, took = run.stop(timeout=60)
    finally:
        for conn in conns:
            conn.close()
    log = run.stderr()
    assert took < SHUTDOWN_TIMEOUT + HARD_STOP_GRACE + 1, f"SIGTERM took {took:.1f} s; {log[-2000:]}"
    assert code in (0, 1), log
    assert not os.path.exists(run.ixm_socket), "the IXM socket was left behind"
    assert "Traceback" not in log


WEDGE = """
import asyncio, sys, time
import mrosd.daemon as d
started = d.Daemon.start
async def start(self):
    await started(self)
    # a part that wedges the event loop, late enough that READY (sent after start) is out first on a loaded machine
    asyncio.get_running_loop().call_later(2.0, time.sleep, 120)
d.Daemon.start = start
sys.exit(d.main(sys.argv[1:]))
"""


def _master_stuck(uri: str) -> bool:
    try:
        _getpid(uri, timeout=0.3)
    except OSError:
        return True
    return False


def test_sigterm_while_a_part_wedges_the_event_loop_still_exits_in_bounded_time_and_removes_the_socket(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    run = DaemonRun(procs, tmp_path, code=WEDGE)
    runs.append(run)
    run.ready()
    deadline = time.monotonic() + 10
    while not _master_stuck(run.uri):
        assert time.monotonic() < deadline, "the harness never wedged the loop"
    assert os.path.exists(run.ixm_socket)
    code, took = run.stop(timeout=30)
    log = run.stderr()
    assert took < SHUTDOWN_TIMEOUT + HARD_STOP_GRACE + 1, f"SIGTERM took {took:.1f} s; {log[-2000:]}"
    assert code == 1, log
    assert "shutdown did not finish" in log
    assert not os.path.exists(run.ixm_socket), "the IXM socket was left behind"


HANG_ON_CLOSE = """
import asyncio, sys
import mrosd.daemon as d, mrosd.rosout as r
async def aclose(self):
    await asyncio.sleep(3600)  # a part whose close never returns
r.RosoutAggregator.aclose = aclose
sys.exit(d.main(sys.argv[1:]))
"""


def test_a_part_whose_close_hangs_does_not_keep_the_others_from_closing(
    procs: Processes, tmp_path: Path, runs: list[DaemonRun]
) -> None:
    run = DaemonRun(procs, tmp_path, code=HANG_ON_CLOSE)
    runs.append(run)
    assert "rosout" in run.ready()
    code, took = run.stop(timeout=30)
    log = run.stderr()
    assert took < SHUTDOWN_TIMEOUT + 1, f"SIGTERM took {took:.1f} s; {log[-2000:]}"
    assert code == 1, log
    assert "closing rosout took longer" in log
    assert not os.path.exists(run.ixm_socket), "the IXM socket was left behind"
