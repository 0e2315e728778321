"""A user who cannot write to the systemd unit's runtime directory still finds its daemon there.

The packaged unit runs mrosd with its IXM socket and status file in ``/run/mrosd`` (``RuntimeDirectory``,
mode 0755, socket 0666). Before, clients looked for the socket only where they could write, so every
non-root user went to ``/tmp/mrosd-<uid>/ixm.sock`` and found nothing. Here a root daemon serves from a
root-owned 0755 directory that stands in for ``/run/mrosd`` (``mrosd.ixm.rundir.SYSTEM_SOCKET`` points at
it: the real path is shared with whatever else runs on the machine), and a process that dropped to
``nobody`` finds the socket and the status file with no setting at all.
"""

from __future__ import annotations

import os
import pwd
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import mrosd.config  # imported before the fork: the child cannot read the interpreter's files under /root
import mrosd.ixm.rundir as rundir
import mrosd.runstatus
from mrosd.ixm import IxmClient
from tests.integration.daemon.daemonproc import DaemonRun, daemon_env
from tests.integration.ixm.test_ixm_users import run_as
from tests.rosenv import Processes

pytestmark = pytest.mark.root


@pytest.fixture
def system_dir() -> Iterator[Path]:
    if os.geteuid() != 0:
        pytest.skip("needs root to run the daemon as root and a client as nobody")
    path = Path(tempfile.mkdtemp(prefix="mrosd-run-", dir="/tmp"))
    path.chmod(0o755)  # as systemd's RuntimeDirectoryMode=0755: others traverse it, only root writes
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def test_a_user_who_cannot_write_the_unit_directory_finds_its_socket_and_status(
    procs: Processes, tmp_path: Path, system_dir: Path
) -> None:
    socket_path = str(system_dir / "ixm.sock")
    run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, MROSD_IXM_SOCKET=socket_path))
    try:
        run.ready()
        nobody = pwd.getpwnam("nobody")

        def as_nobody() -> dict[str, Any]:
            for name in ("MROSD_IXM_SOCKET", "XDG_RUNTIME_DIR"):
                os.environ.pop(name, None)
            rundir.SYSTEM_SOCKET = socket_path
            assert not os.access(system_dir, os.W_OK)
            with IxmClient(name="probe") as client:
                client.list()
                found = client.socket_path
            status = mrosd.runstatus.find_status(run.uri, rundir.client_run_dirs())
            return {"socket": found, "master": status.master_uri if status else None, "config": mrosd.config.__name__}

        seen = run_as(nobody, as_nobody)
    finally:
        run.stop()
        run.close()
    assert seen["socket"] == socket_path
    assert seen["master"] == run.uri
