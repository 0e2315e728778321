"""``mros bridge`` on a port in use: one ``ERROR:`` line naming the port, exit 1; before, a traceback."""

from __future__ import annotations

import socket
import subprocess
import sys

from tests.interop.cli.cliutil import mros_env, start_our_master
from tests.rosenv import Processes


def test_a_bridge_port_in_use_is_one_line_naming_it(procs: Processes) -> None:
    uri = start_our_master(procs)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "mros_cli.main", "bridge", "--port", str(port), "--rosbridge-port", "-1"],
            env=mros_env(uri, procs.tmp),
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    assert done.returncode == 1
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("ERROR: ") and str(port) in lines[0] and "in use" in lines[0].lower()
