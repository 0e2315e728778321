"""``mros ixm write --hold`` ends on SIGTERM as on Ctrl-C: it releases the key and exits 0, quietly.

Before, only SIGINT reached its ``sigwait`` (and as a KeyboardInterrupt, status 130); SIGTERM killed it.
"""

from __future__ import annotations

import signal
import sys

import pytest

from mrosd.ixm import IxmClient
from tests.integration.ixm.conftest import until
from tests.rosenv import PROJECT_ROOT, Processes


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_hold_releases_the_key_and_exits_0_on_a_stop_signal(
    ixm_socket: str, procs: Processes, signum: signal.Signals
) -> None:
    argv = [sys.executable, "-m", "mros_cli.main", "ixm", "--socket", ixm_socket]
    proc = procs.start(
        [*argv, "write", "/held", "7", "--type", "int32", "--hold"],
        {"PYTHONPATH": f"{PROJECT_ROOT}:{PROJECT_ROOT / 'cli'}", "PATH": "/usr/bin:/bin"},
    )
    assert proc.stderr is not None
    assert proc.stderr.readline().startswith(b"holding /held")
    with IxmClient(ixm_socket) as probe:
        assert probe.list("/held").segments
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=10)
        assert (proc.returncode, err.decode()) == (0, "")
        until(lambda: not probe.list().segments)
