"""mrosd started as systemd starts it: NOTIFY_SOCKET, JOURNAL_STREAM, WATCHDOG_USEC, then SIGTERM.

The test plays systemd's part with a real AF_UNIX datagram socket and a real daemon subprocess.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path

from tests.rosenv import Processes, free_port


def _daemon_env(tmp: Path, notify: str, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_", "NOTIFY_", "WATCHDOG_"))}
    env.update(
        NOTIFY_SOCKET=notify,
        JOURNAL_STREAM="8:12345",
        MROSD_IXM_SOCKET=str(tmp / "run" / "ixm.sock"),
        ROS_HOSTNAME="127.0.0.1",
        PYTHONUNBUFFERED="1",
    )
    env.update(extra)
    return env


def _receive_until(sock: socket.socket, wanted: str, timeout: float) -> list[str]:
    """Datagrams until one contains the line ``wanted``; fails the test after ``timeout`` seconds."""
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError(f"no {wanted} within {timeout} s; got {seen}")
        sock.settimeout(remaining)
        msg = sock.recv(4096).decode()
        seen.append(msg)
        if wanted in msg.split("\n"):
            return seen


def test_the_daemon_notifies_ready_once_the_master_answers_and_exits_cleanly_on_sigterm(
    procs: Processes, tmp_path: Path
) -> None:
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify_path = str(tmp_path / "notify.sock")
    notify.bind(notify_path)
    port = free_port()
    env = _daemon_env(tmp_path, notify_path, WATCHDOG_USEC="400000")
    proc = procs.our_python(["-m", "mrosd.daemon", "--port", str(port)], env)
    try:
        _receive_until(notify, "READY=1", timeout=30)
        # READY means the master answers now, not eventually.
        with xmlrpc.client.ServerProxy(f"http://127.0.0.1:{port}/") as proxy:
            assert proxy.getPid("/test")[0] == 1
        _receive_until(notify, "WATCHDOG=1", timeout=5)
        start = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        _receive_until(notify, "STOPPING=1", timeout=5)
        assert proc.wait(timeout=10) == 0
        assert time.monotonic() - start < 10
    finally:
        notify.close()
    assert proc.stderr is not None
    lines = proc.stderr.read().decode().splitlines()
    assert lines, "the daemon logged nothing"
    assert all(line.startswith("<") and line[2] == ">" for line in lines), lines
    assert any(line.startswith("<6>") and "ready" in line for line in lines)
    assert not (tmp_path / "run" / "ixm.sock").exists()


def test_a_port_already_in_use_is_a_one_line_error_and_exit_code_1(procs: Processes, tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("0.0.0.0", 0))
        busy.listen()
        port = busy.getsockname()[1]
        env = _daemon_env(tmp_path, "", MROSD_ROSOUT="0", MROSD_IXM="0")
        proc = procs.our_python(["-m", "mrosd.daemon", "--port", str(port)], env)
        assert proc.wait(timeout=30) == 1
    assert proc.stderr is not None
    assert "cannot start" in proc.stderr.read().decode()


def check_config(path: Path) -> subprocess.CompletedProcess[str]:
    """``mrosd --config PATH --check-config``, its output captured."""
    return subprocess.run(
        [sys.executable, "-m", "mrosd.daemon", "--config", str(path), "--check-config"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_check_config_rejects_a_bad_file_with_exit_code_2_naming_the_key(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[master]\nport = 'eleven'\n")
    out = check_config(bad)
    assert out.returncode == 2
    assert "master.port" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_check_config_accepts_the_packaged_example(tmp_path: Path) -> None:
    example = Path(__file__).resolve().parents[3] / "packaging" / "mrosd.toml"
    out = check_config(example)
    assert out.returncode == 0, out.stderr
    assert "configuration OK" in out.stdout


def test_check_config_validates_the_ixm_access_rules_naming_the_key(tmp_path: Path) -> None:
    bad = tmp_path / "rules.toml"
    bad.write_text('[ixm.rules.keys."/cam"]\nread_uids = ["no-such-user-here"]\n')
    out = check_config(bad)
    assert out.returncode == 2
    assert str(bad) in out.stderr
    assert 'ixm.rules.keys."/cam".read_uids' in out.stderr


def test_sighup_reloads_the_ixm_rules_and_keeps_running_on_a_broken_file(procs: Processes, tmp_path: Path) -> None:
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify_path = str(tmp_path / "notify.sock")
    notify.bind(notify_path)
    config = tmp_path / "mrosd.toml"
    config.write_text('[ixm.rules]\ndefault = "creator"\n[rosout]\nenabled = false\n')
    port = free_port()
    env = _daemon_env(tmp_path, notify_path)
    proc = procs.our_python(["-m", "mrosd.daemon", "--config", str(config), "--port", str(port)], env)
    try:
        _receive_until(notify, "READY=1", timeout=30)
        config.write_text('[ixm.rules]\ndefault = "deny"\n[rosout]\nenabled = false\n')
        proc.send_signal(signal.SIGHUP)
        _receive_until(notify, "RELOADING=1", timeout=10)
        _receive_until(notify, "READY=1", timeout=10)
        config.write_text('[ixm.rules]\ndefault = "sometimes"\n')
        proc.send_signal(signal.SIGHUP)
        _receive_until(notify, "RELOADING=1", timeout=10)
        _receive_until(notify, "READY=1", timeout=10)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        notify.close()
    assert proc.stderr is not None
    log = proc.stderr.read().decode()
    assert "SIGHUP: IXM access rules reloaded" in log
    assert "reload failed, keeping the running configuration" in log
    assert "ixm.rules.default" in log
