"""Fixtures shared by every test layer."""

from __future__ import annotations

import gc
import os
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from tests.rosenv import Processes, start_rosmaster

if TYPE_CHECKING:
    from mrosd.master import Master

# Every mrosd daemon a test starts (and that inherits this environment) serves its web part on a free port:
# tests run in parallel, and the default 8765 may belong to a daemon the developer runs.
os.environ.setdefault("MROSD_WEB_PORT", "0")
os.environ.setdefault("MROSD_WEB_ROSBRIDGE_PORT", "0")


@pytest.fixture(autouse=True, scope="session")
def _log_files_in_a_temporary_directory(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Daemons and ROS tools started by tests write their log files (``<run_id>/master.log``, ...) here, not
    into the developer's ``~/.ros/log`` (helpers that build an environment from scratch set their own)."""
    saved = os.environ.get("ROS_LOG_DIR")
    os.environ["ROS_LOG_DIR"] = str(tmp_path_factory.mktemp("ros_log"))
    yield
    if saved is None:
        os.environ.pop("ROS_LOG_DIR", None)
    else:
        os.environ["ROS_LOG_DIR"] = saved


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    """Start subprocesses that are all killed when the test ends."""
    p = Processes(tmp_path)
    try:
        yield p
    finally:
        p.close()


@pytest.fixture
async def master() -> AsyncIterator[Master]:
    """mrosd's ``Master`` in the test's event loop, on 127.0.0.1 and a free port, with its default settings
    (a module whose tests need other settings, or a daemon process, defines its own ``master``)."""
    from mrosd.master import Master  # imported here: collecting a test must not load the master

    async with Master(host="127.0.0.1", port=0) as m:
        yield m


@pytest.fixture
def rosmaster(procs: Processes) -> str:
    """URI of a real Debian ``rosmaster --core`` on a free port (interop tests only)."""
    return start_rosmaster(procs)


def pytest_collection_finish(session: pytest.Session) -> None:
    """Everything imported and collected so far lives for the whole run: keep it out of the collector's way,
    so the collection after each test (below) costs what that test left, not the size of the heap."""
    gc.collect()
    gc.freeze()


@pytest.fixture(autouse=True)
def _collect_garbage_after_each_test() -> Iterator[None]:
    """Collect cycles when each test ends, so an unclosed socket or transport fails the test that leaked it.

    Without this, a leak surfaces at whatever later moment the collector happens to run, in another test.
    """
    yield
    gc.collect()
