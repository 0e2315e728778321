"""Fixtures shared by every test layer."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.rosenv import Processes, start_rosmaster


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    """Start subprocesses that are all killed when the test ends."""
    p = Processes(tmp_path)
    try:
        yield p
    finally:
        p.close()


@pytest.fixture
def rosmaster(procs: Processes) -> str:
    """URI of a real Debian ``rosmaster --core`` on a free port (interop tests only)."""
    return start_rosmaster(procs)
