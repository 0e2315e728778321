"""`mros topic pub -f FILE` and piped stdin publish one message per YAML document, heard by rostopic echo."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, mros_process
from tests.rosenv import Processes, iter_lines_until, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

DOCS = "data: one\n---\ndata: two\n---\ndata: three\n"


def test_each_document_of_a_file_is_published_once_in_order(procs: Processes, rosmaster: str) -> None:
    doc = procs.tmp / "msgs.yaml"
    doc.write_text(DOCS)
    echo = procs.start(["rostopic", "echo", "-n", "3", "/fromfile"], ros_env(rosmaster, procs.tmp))
    pub = mros_process(procs, rosmaster, "topic", "pub", "-r", "20", "/fromfile", "std_msgs/String", "-f", str(doc))
    assert list(iter_lines_until(echo, 6, timeout=30)) == [
        'data: "one"',
        "---",
        'data: "two"',
        "---",
        'data: "three"',
        "---",
    ]
    assert pub.wait(timeout=30) == 0


def test_mros_echo_output_piped_to_pub_on_stdin_is_republished(procs: Processes, rosmaster: str) -> None:
    echo = procs.start(["rostopic", "echo", "-n", "2", "/fromstdin"], ros_env(rosmaster, procs.tmp))
    pub = mros_process(
        procs, rosmaster, "topic", "pub", "-r", "50", "/fromstdin", "std_msgs/String", stdin=subprocess.PIPE
    )
    assert pub.stdin is not None
    pub.stdin.write(b'data: "first"\n---\ndata: "second"\n---\n')
    pub.stdin.close()
    assert list(iter_lines_until(echo, 4, timeout=30)) == ['data: "first"', "---", 'data: "second"', "---"]
    assert pub.wait(timeout=30) == 0


def test_a_bad_document_in_a_file_fails_before_anything_is_published(rosmaster: str, tmp_path: Path) -> None:
    doc = tmp_path / "bad.yaml"
    doc.write_text("{x: 1.0}\n---\n{x: 2.0, nope: 3}\n")
    out = mros(rosmaster, tmp_path, "topic", "pub", "/never", "geometry_msgs/Point", "-f", str(doc))
    assert out.returncode == 1
    assert out.stderr.startswith("ERROR: ") and "nope" in out.stderr
    assert out.stderr.endswith("\n\nArgs are: [x y z]\n")  # rostopic pub's hint
    topics = mros(rosmaster, tmp_path, "topic", "list").stdout.split()
    assert "/never" not in topics
