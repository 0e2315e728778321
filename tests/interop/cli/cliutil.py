"""Run `mros` and the Debian ROS tools side by side on the same master (shared by the CLI interop tests)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.rosenv import ros_env


def mros(master_uri: str, tmp: Path, *args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    """``mros ARGS`` under the project's python, pointed at ``master_uri``."""
    env = ros_env(master_uri, tmp)
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", *args],
        env=env,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def ros_tool(master_uri: str, tmp: Path, *argv: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    """A Debian ROS command-line tool (rosparam, rosnode, rostopic, rosservice) on ``master_uri``."""
    return subprocess.run(
        list(argv),
        env=ros_env(master_uri, tmp),
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
