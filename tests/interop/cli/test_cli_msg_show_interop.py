"""`mros msg show` / `mros srv show` print byte for byte what rosmsg / rossrv print, trailing blank line included.

Full names for every type of the installed message packages (rosmsg's own text functions, plus the newline
its ``print`` adds), and short names through the real command-line tools: found in one package, found in
several (each under a ``[pkg/Type]:`` line, in rosmsg's package order), and not found at all.
"""

from __future__ import annotations

import concurrent.futures
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from mros_cli.main import cli

from tests.rosenv import ROS_PYTHON, needs_ros

pytestmark = [needs_ros, pytest.mark.interop]

ROSMSG_TEXTS = """
import json, rosmsg, rospkg
packs = rospkg.RosPack()
out = {}
for pkg in ("std_msgs", "geometry_msgs", "sensor_msgs", "rosgraph_msgs"):
    for name in rosmsg.list_types(pkg, rospack=packs):
        out[name] = [rosmsg.get_msg_text(name, rospack=packs) + "\\n",
                     rosmsg.get_msg_text(name, raw=True, rospack=packs) + "\\n"]
print(json.dumps(out))
"""


def test_show_of_every_installed_type_is_byte_identical_to_rosmsg() -> None:
    proc = subprocess.run([ROS_PYTHON, "-c", ROSMSG_TEXTS], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    expected = json.loads(proc.stdout)
    assert len(expected) > 80
    runner = CliRunner()
    for name, (shown, raw) in expected.items():
        ours = runner.invoke(cli, ["msg", "show", name])
        assert (ours.exit_code, ours.output) == (0, shown), name
        ours_raw = runner.invoke(cli, ["msg", "show", "-r", name])
        assert (ours_raw.exit_code, ours_raw.output) == (0, raw), name


def _package(root: Path, name: str, definitions: dict[str, str]) -> None:
    """A package with ``Type.msg`` / ``Type.srv`` files (keys name the file)."""
    (root / name / "msg").mkdir(parents=True)
    (root / name / "srv").mkdir()
    (root / name / "package.xml").write_text(
        f'<package format="2"><name>{name}</name><version>1.0.0</version><description>t</description>'
        '<maintainer email="t@example.com">t</maintainer><license>BSD</license></package>\n'
    )
    for file_name, text in definitions.items():
        (root / name / file_name.rpartition(".")[2] / file_name).write_text(text)


def _both(env: dict[str, str], tool: str, *args: str) -> tuple[subprocess.CompletedProcess[str], ...]:
    """The ROS tool and mros on the same arguments, run at the same time."""
    noun = {"rosmsg": "msg", "rossrv": "srv"}[tool]
    argvs = ([tool, *args], [sys.executable, "-m", "mros_cli.main", noun, *args])
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        runs = [
            pool.submit(subprocess.run, argv, env=env, capture_output=True, text=True, timeout=60, check=False)
            for argv in argvs
        ]
        return tuple(run.result() for run in runs)


def test_short_names_resolve_and_list_every_candidate_as_rosmsg(tmp_path: Path) -> None:
    rpp = tmp_path / "src"
    # Twist clashes with geometry_msgs; Coord exists in two of our packages, one a level deeper.
    add = "int64 a\nint64 b\n---\nint64 sum\n"
    _package(
        rpp,
        "aaa_msgs",
        {"Twist.msg": "# a comment\nint32 a  # trailing\nstring s\n", "Coord.msg": "float64 x\n", "Add.srv": add},
    )
    _package(rpp / "nested", "zzz_msgs", {"Coord.msg": "geometry_msgs/Point p\nHeader header\n", "Add.srv": add})
    env = {
        "PATH": "/usr/bin:/bin",
        "HOME": str(tmp_path),
        "ROS_PACKAGE_PATH": str(rpp),
        "PYTHONPATH": os.environ.get("PYTHONPATH", ""),
    }
    for args in (
        ["show", "Twist"],
        ["show", "Coord"],
        ["show", "-r", "Coord"],
        ["show", "Header"],
        ["show", "Log"],
        ["show", "Point32"],
        ["show", "String.msg"],
        ["show", "aaa_msgs/Twist"],
        ["show", "NoSuchType"],
    ):
        theirs, ours = _both(env, "rosmsg", *args)
        assert (ours.returncode, ours.stdout) == (theirs.returncode, theirs.stdout), args
        if theirs.returncode:
            assert ours.stderr == theirs.stderr, args
    # Debian installs no .srv files, so the services come from our packages.
    for args in (["show", "aaa_msgs/Add"], ["show", "Add"], ["show", "-r", "zzz_msgs/Add"], ["show", "Nope"]):
        theirs, ours = _both(env, "rossrv", *args)
        assert (ours.returncode, ours.stdout) == (theirs.returncode, theirs.stdout), args
