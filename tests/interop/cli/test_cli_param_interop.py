"""`mros param` against real rosmaster gives what `rosparam` gives: same stdout, same exit code."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, ros_tool
from tests.rosenv import needs_ros

pytestmark = [needs_ros, pytest.mark.interop]

SETS = [
    ("/int", "42"),
    ("/neg", "-7"),
    ("/float", "1.5"),
    ("/str", "hello world"),
    ("/numstr", "'42'"),
    ("/flag", "true"),
    ("/list", "[1, 2.5, three]"),
    ("/dict", "{a: 1, b: {c: [1, 2]}, s: x}"),
]


def test_values_set_by_mros_read_back_identically_with_rosparam_and_mros(rosmaster: str, tmp_path: Path) -> None:
    # The cases are independent: run them side by side (each tool takes ~1 s to start).
    with ThreadPoolExecutor(max_workers=4) as pool:
        sets = list(pool.map(lambda nv: mros(rosmaster, tmp_path, "param", "set", *nv), SETS))
        assert [r.returncode for r in sets] == [0] * len(SETS), [r.stderr for r in sets]
        names = [name for name, _ in SETS] + ["/dict/b", "/"]
        ours = list(pool.map(lambda n: mros(rosmaster, tmp_path, "param", "get", n), names))
        theirs = list(pool.map(lambda n: ros_tool(rosmaster, tmp_path, "rosparam", "get", n), names))
    for name, o, t in zip(names, ours, theirs, strict=True):
        assert (o.returncode, o.stdout) == (t.returncode, t.stdout), name


def test_list_and_namespace_list_match_rosparam(rosmaster: str, tmp_path: Path) -> None:
    ros_tool(rosmaster, tmp_path, "rosparam", "set", "/robot", "{arm: {joints: 6}, name: r2, wheels: [1, 2]}")
    for ns in ([], ["/robot"], ["/robot/arm"], ["/nothing"]):
        ours = mros(rosmaster, tmp_path, "param", "list", *ns)
        theirs = ros_tool(rosmaster, tmp_path, "rosparam", "list", *ns)
        assert ours.stdout == theirs.stdout, ns
        assert ours.returncode == theirs.returncode == 0


def test_getting_a_missing_parameter_fails_with_exit_code_1_and_one_stderr_line(rosmaster: str, tmp_path: Path) -> None:
    ours = mros(rosmaster, tmp_path, "param", "get", "/missing")
    theirs = ros_tool(rosmaster, tmp_path, "rosparam", "get", "/missing")
    assert ours.returncode == theirs.returncode == 1
    assert ours.stdout == ""
    assert ours.stderr.strip() == "ERROR: Parameter [/missing] is not set"


def test_delete_removes_what_rosparam_set(rosmaster: str, tmp_path: Path) -> None:
    ros_tool(rosmaster, tmp_path, "rosparam", "set", "/gone", "{a: 1, b: 2}")
    assert mros(rosmaster, tmp_path, "param", "delete", "/gone/a").returncode == 0
    assert ros_tool(rosmaster, tmp_path, "rosparam", "get", "/gone").stdout == "b: 2\n\n"
    assert mros(rosmaster, tmp_path, "param", "delete", "/gone").returncode == 0
    assert ros_tool(rosmaster, tmp_path, "rosparam", "get", "/gone").returncode == 1


def test_dump_matches_rosparam_dump_and_load_round_trips(rosmaster: str, tmp_path: Path) -> None:
    ros_tool(rosmaster, tmp_path, "rosparam", "set", "/cfg", "{gains: [1.0, 2.0], mode: fast, limits: {v: 3}}")
    ours = mros(rosmaster, tmp_path, "param", "dump", "-", "/cfg")
    theirs = ros_tool(rosmaster, tmp_path, "rosparam", "dump", "/dev/stdout", "/cfg")
    assert ours.returncode == 0
    assert ours.stdout == theirs.stdout
    dump = tmp_path / "cfg.yaml"
    dump.write_text(ours.stdout)
    assert mros(rosmaster, tmp_path, "param", "load", str(dump), "/copy").returncode == 0
    assert (
        mros(rosmaster, tmp_path, "param", "get", "/copy").stdout
        == ros_tool(rosmaster, tmp_path, "rosparam", "get", "/cfg").stdout
    )


def test_load_honours_the_ns_key_of_each_document_like_rosparam(rosmaster: str, tmp_path: Path) -> None:
    doc = tmp_path / "multi.yaml"
    doc.write_text("_ns: first\nx: 1\n---\n_ns: second\ny: 2\n")
    assert mros(rosmaster, tmp_path, "param", "load", str(doc), "/m").returncode == 0
    ros_tool(rosmaster, tmp_path, "rosparam", "load", str(doc), "/r")
    assert (
        mros(rosmaster, tmp_path, "param", "get", "/m").stdout == mros(rosmaster, tmp_path, "param", "get", "/r").stdout
    )


def test_bad_yaml_and_oversized_integers_are_one_line_errors(rosmaster: str, tmp_path: Path) -> None:
    bad = mros(rosmaster, tmp_path, "param", "set", "/x", "{unclosed: [1,")
    assert bad.returncode == 1
    assert bad.stderr.startswith("ERROR: value is not valid YAML")
    assert len(bad.stderr.strip().splitlines()) == 1
    big = mros(rosmaster, tmp_path, "param", "set", "/x", "99999999999")
    assert big.returncode == 1
    assert "/x" in big.stderr


def test_a_missing_argument_is_a_usage_error_with_exit_code_2(rosmaster: str, tmp_path: Path) -> None:
    assert mros(rosmaster, tmp_path, "param", "get").returncode == 2
    assert mros(rosmaster, tmp_path, "param", "frobnicate").returncode == 2
