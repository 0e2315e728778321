"""Run `mros` and the Debian ROS tools side by side on the same master (shared by the CLI interop tests)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.rosenv import PROJECT_ROOT, Processes, free_port, ros_env, wait_for_xmlrpc


def mros_env(master_uri: str, tmp: Path) -> dict[str, str]:
    """``ros_env`` plus this checkout on PYTHONPATH: ``mros`` runs the code under test, not an installed copy."""
    return ros_env(master_uri, tmp, PYTHONPATH=f"{PROJECT_ROOT}:{PROJECT_ROOT / 'cli'}")


def mros(
    master_uri: str, tmp: Path, *args: str, stdin: str | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    """``mros ARGS`` under the project's python, pointed at ``master_uri``."""
    env = mros_env(master_uri, tmp)
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", *args],
        env=env,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def ros_tool(
    master_uri: str, tmp: Path, *argv: str, stdin: str | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    """A Debian ROS command-line tool (rosparam, rosnode, rostopic, rosservice) on ``master_uri``."""
    return subprocess.run(
        list(argv),
        env=ros_env(master_uri, tmp),
        input=stdin,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def start_our_master(procs: Processes) -> str:
    """Start our master (``python -m mrosd.master``) on a free port; return its URI once it answers."""
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    procs.our_python(
        ["-m", "mrosd.master", "--port", str(port)],
        ros_env(uri, procs.tmp),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc(uri)
    return uri


def start_rospy(procs: Processes, code: str, master_uri: str, **kw: int | None) -> subprocess.Popen[bytes]:
    """Run a rospy script (it prints ``up`` once its graph is in place) and wait for that line."""
    node = procs.python(code, ros_env(master_uri, procs.tmp), **kw)
    assert node.stdout is not None
    assert node.stdout.readline().strip() == b"up"
    return node


def mros_process(
    procs: Processes, master_uri: str, *args: str, stdin: int | None = subprocess.DEVNULL
) -> subprocess.Popen[bytes]:
    """``mros ARGS`` as a long-running process (pub, echo), killed when the test ends."""
    return procs.start([sys.executable, "-m", "mros_cli.main", *args], mros_env(master_uri, procs.tmp), stdin=stdin)


def mask_seq(text: str) -> str:
    """rospy stamps each subscriber's copy of a latched message with its own header.seq: mask it (in echo's
    ``seq: N`` lines and in the second column of ``echo -p`` rows)."""
    return re.sub(r"(?m)^(%?\d+),\d+,", r"\1,<seq>,", re.sub(r"seq: \d+", "seq: <seq>", text))
