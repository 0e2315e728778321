"""`mros msg` and `mros srv`: show/md5/list print what rosmsg/rossrv print; gen writes importable packages."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from mros_cli.main import cli

COORDINATE = Path(__file__).resolve().parents[2] / "data" / "msg" / "mros_test_msgs"


def invoke(*argv: str) -> tuple[int, str]:
    result = CliRunner().invoke(cli, list(argv))
    return result.exit_code, result.output


def _commands() -> list[list[str]]:
    ctx = click.Context(cli)
    out = []
    for noun in ("msg", "srv"):
        group = cli.get_command(ctx, noun)
        assert isinstance(group, click.Group)
        out += [[noun], *([noun, verb] for verb in group.list_commands(ctx))]
    return out


@pytest.mark.parametrize("argv", _commands(), ids=" ".join)
def test_every_msg_and_srv_command_has_help_with_an_example(argv: list[str]) -> None:
    code, output = invoke(*argv, "--help")
    assert code == 0, output
    assert "Example" in output


def test_show_prints_constants_first_and_nested_fields_indented() -> None:
    code, output = invoke("msg", "show", "rosgraph_msgs/Log")
    assert code == 0
    lines = output.splitlines()
    assert lines[:6] == [
        "byte DEBUG=1",
        "byte INFO=2",
        "byte WARN=4",
        "byte ERROR=8",
        "byte FATAL=16",
        "std_msgs/Header header",
    ]
    assert lines[6:9] == ["  uint32 seq", "  time stamp", "  string frame_id"]
    assert lines[-2:] == ["string[] topics", ""]


def test_show_raw_and_full_print_the_definition_texts() -> None:
    code, output = invoke("msg", "show", "-r", "std_msgs/String")
    assert (code, output) == (0, "string data\n\n")
    code, output = invoke("msg", "show", "--full", "geometry_msgs/PoseStamped")
    assert code == 0
    assert "MSG: std_msgs/Header" in output


def test_md5_prints_one_line_per_type() -> None:
    code, output = invoke("msg", "md5", "std_msgs/String", "std_msgs/Header")
    assert code == 0
    assert output.split() == ["992ce8a1687cec8c8bd883ec73ca41d1", "2176decaecbce78abc3b96ef049fabed"]


def test_user_types_are_found_through_include_directories() -> None:
    code, output = invoke("msg", "show", "-I", f"mros_test_msgs:{COORDINATE}", "mros_test_msgs/Coordinate")
    assert (code, output) == (0, "float32 x\nfloat32 y\nfloat32 z\ntime time\n\n")
    code, output = invoke("msg", "list", "-I", f"mros_test_msgs:{COORDINATE}", "mros_test_msgs")
    assert (code, output) == (0, "mros_test_msgs/Coordinate\n")


def test_list_includes_the_shipped_standard_types() -> None:
    code, output = invoke("msg", "list")
    assert code == 0
    for name in ("std_msgs/String", "sensor_msgs/Image", "rosgraph_msgs/Clock", "nav_msgs/Odometry"):
        assert name in output.splitlines()


def test_srv_show_md5_and_list() -> None:
    assert invoke("srv", "show", "std_srvs/SetBool") == (0, "bool data\n---\nbool success\nstring message\n\n")
    assert invoke("srv", "md5", "std_srvs/SetBool") == (0, "09fb03525b03e7ea1fd3992bafd87e16\n")
    code, output = invoke("srv", "list", "std_srvs")
    assert code == 0
    assert "std_srvs/Trigger" in output.splitlines()


def test_unknown_types_and_bad_includes_exit_1_with_one_error_line() -> None:
    result = CliRunner().invoke(cli, ["msg", "show", "nope_msgs/Nope"])
    assert result.exit_code == 1
    assert "unknown msg type 'nope_msgs/Nope'" in result.output
    result = CliRunner().invoke(cli, ["msg", "md5", "-I", "nocolon", "std_msgs/String"])
    assert result.exit_code == 1
    assert "PACKAGE:DIRECTORY" in result.output


def test_gen_writes_packages_that_import_and_round_trip(tmp_path: Path) -> None:
    code, output = invoke(
        "msg", "gen", "-I", f"mros_test_msgs:{COORDINATE}", "-o", str(tmp_path), "mros_test_msgs", "std_srvs"
    )
    assert code == 0, output
    assert (tmp_path / "mros_test_msgs" / "msg" / "_Coordinate.py").is_file()
    script = (
        "from mros_test_msgs.msg import Coordinate\n"
        "from std_srvs.srv import SetBool, SetBoolRequest\n"
        "from mrosd.msg import Time\n"
        "c = Coordinate(x=1.5, time=Time(3, 4))\n"
        "assert Coordinate.deserialize(c.serialize()) == c\n"
        "assert Coordinate._md5sum == '150ec92f7b2a8bc129be1382f52a987e'\n"
        "assert SetBool._md5sum == '09fb03525b03e7ea1fd3992bafd87e16'\n"
        "assert SetBoolRequest(data=True).serialize() == b'\\x01'\n"
        "print('ok')\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.stdout == "ok\n", proc.stderr


def test_gen_without_targets_or_includes_is_a_clear_error(tmp_path: Path) -> None:
    result = CliRunner().invoke(cli, ["msg", "gen", "-o", str(tmp_path)])
    assert result.exit_code == 1
    assert "nothing to generate" in result.output
