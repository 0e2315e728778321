"""`mros msg show/md5` print exactly what Debian's rosmsg prints, for every type rosmsg can find."""

from __future__ import annotations

import json
import subprocess

from click.testing import CliRunner
from mros_cli.main import cli

from tests.rosenv import ROS_PYTHON, needs_ros

pytestmark = needs_ros

ROSMSG_SCRIPT = """
import json, rosmsg, rospkg
out = {}
packs = rospkg.RosPack()
for pkg in ("std_msgs", "geometry_msgs", "sensor_msgs", "rosgraph_msgs"):
    for name in rosmsg.list_types(pkg, rospack=packs):
        out[name] = {"show": rosmsg.get_msg_text(name, rospack=packs),
                     "raw": rosmsg.get_msg_text(name, raw=True, rospack=packs)}
print(json.dumps(out))
"""


def test_show_and_raw_show_match_rosmsg_for_every_type_it_knows() -> None:
    proc = subprocess.run([ROS_PYTHON, "-c", ROSMSG_SCRIPT], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    expected = json.loads(proc.stdout)
    assert len(expected) > 80
    runner = CliRunner()
    for name, texts in expected.items():
        shown = runner.invoke(cli, ["msg", "show", name])
        assert shown.exit_code == 0, shown.output
        assert shown.output.rstrip("\n") == texts["show"].rstrip("\n"), name
        raw = runner.invoke(cli, ["msg", "show", "-r", name])
        assert raw.output.rstrip("\n") == texts["raw"].rstrip("\n"), name


def test_md5_matches_rosmsg_md5() -> None:
    names = ["std_msgs/String", "geometry_msgs/PoseStamped", "sensor_msgs/Image", "rosgraph_msgs/Log"]
    theirs = []
    for name in names:
        proc = subprocess.run(["rosmsg", "md5", name], capture_output=True, text=True, timeout=60, check=False)
        assert proc.returncode == 0, proc.stderr
        theirs.append(proc.stdout.strip())
    ours = CliRunner().invoke(cli, ["msg", "md5", *names])
    assert ours.exit_code == 0
    assert ours.output.split() == theirs
