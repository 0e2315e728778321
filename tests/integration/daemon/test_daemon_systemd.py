"""mrosd started as systemd starts it: NOTIFY_SOCKET, JOURNAL_STREAM, WATCHDOG_USEC, then SIGTERM.

The test plays systemd's part with a real AF_UNIX datagram socket and a real daemon subprocess.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path

import pytest

from tests.integration.daemon.daemonproc import DaemonRun, daemon_env
from tests.rosenv import Processes


def test_the_daemon_notifies_ready_once_the_master_answers_and_exits_cleanly_on_sigterm(
    procs: Processes, tmp_path: Path
) -> None:
    run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, WATCHDOG_USEC="400000"))
    try:
        run.ready()
        # READY means the master answers now, not eventually.
        with xmlrpc.client.ServerProxy(run.uri) as proxy:
            assert proxy.getPid("/test")[0] == 1
        run.notify.until("WATCHDOG=1", timeout=5)
        start = time.monotonic()
        run.signal(signal.SIGTERM)
        run.notify.until("STOPPING=1", timeout=5)
        assert run.proc.wait(timeout=10) == 0
        assert time.monotonic() - start < 10
    finally:
        run.close()
    lines = run.stderr().splitlines()
    assert lines, "the daemon logged nothing"
    assert all(line.startswith("<") and line[2] == ">" for line in lines), lines
    assert any(line.startswith("<6>") and "ready" in line for line in lines)
    assert not (tmp_path / "run" / "ixm.sock").exists()


def test_a_port_already_in_use_is_a_one_line_error_and_exit_code_1(procs: Processes, tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("0.0.0.0", 0))
        busy.listen()
        env = daemon_env(tmp_path, MROSD_ROSOUT="0", MROSD_IXM="0")
        run = DaemonRun(procs, tmp_path, env=env, port=busy.getsockname()[1])
        assert run.proc.wait(timeout=30) == 1
    run.close()
    assert "cannot start" in run.stderr()


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
    config = tmp_path / "mrosd.toml"
    config.write_text('[ixm.rules]\ndefault = "creator"\n[rosout]\nenabled = false\n')
    run = DaemonRun(procs, tmp_path, "--config", str(config))
    try:
        run.ready()
        config.write_text('[ixm.rules]\ndefault = "deny"\n[rosout]\nenabled = false\n')
        run.signal(signal.SIGHUP)
        run.notify.until("RELOADING=1", timeout=10)
        run.notify.until("READY=1", timeout=10)
        config.write_text('[ixm.rules]\ndefault = "sometimes"\n')
        run.signal(signal.SIGHUP)
        run.notify.until("RELOADING=1", timeout=10)
        run.notify.until("READY=1", timeout=10)
        assert run.stop()[0] == 0
    finally:
        run.close()
    log = run.stderr()
    assert "SIGHUP: IXM access rules reloaded" in log
    assert "reload failed, keeping the running configuration" in log
    assert "ixm.rules.default" in log


def test_check_config_refuses_a_toml_nested_5000_deep_in_one_line(tmp_path: Path) -> None:
    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    out = check_config(deep)
    assert out.returncode == 2, out.stderr
    assert out.stderr.count("\n") == 1 and "nested" in out.stderr and str(deep) in out.stderr, out.stderr


def test_check_config_refuses_a_master_host_that_is_not_an_address(tmp_path: Path) -> None:
    bad = tmp_path / "host.toml"
    bad.write_text('[master]\nhost = "999.1.1.1"\n')
    out = check_config(bad)
    assert out.returncode == 2, out.stdout
    assert out.stderr.count("\n") == 1 and "master.host" in out.stderr and "999.1.1.1" in out.stderr


def test_check_config_validates_the_ixm_bridges_the_daemon_runs(tmp_path: Path) -> None:
    bad = tmp_path / "bridge.toml"
    bad.write_text('[ixm.rules.bridges."/arm"]\ntype = "std_msgs/Float64"\ndirektion = "to_topic"\n')
    out = check_config(bad)
    assert out.returncode == 2, out.stdout
    assert out.stderr.count("\n") == 1 and 'bridges."/arm"' in out.stderr and "direktion" in out.stderr


@pytest.mark.parametrize("text", ["[bridges]\n", "[master]\nidle_timeot = 5\n", "[ixm]\nmax_key = 5\n"])
def test_check_config_refuses_unknown_sections_and_keys_naming_them(tmp_path: Path, text: str) -> None:
    bad = tmp_path / "unknown.toml"
    bad.write_text(text)
    out = check_config(bad)
    assert out.returncode == 2, out.stdout
    name = text.strip().split("\n")[-1].split(" ")[0].strip("[]")
    assert out.stderr.count("\n") == 1 and name in out.stderr, out.stderr
