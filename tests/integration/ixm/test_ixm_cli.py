"""``mros ixm`` against a real daemon: list, show, read (and --follow woken by a write), write, errors."""

from __future__ import annotations

import subprocess
import sys

from click.testing import CliRunner
from mros_cli.main import cli

from mrosd.ixm import IxmClient


def mros(sock: str, *args: str) -> tuple[int, str]:
    result = CliRunner().invoke(cli, ["ixm", "--socket", sock, *args])
    return result.exit_code, result.output


def test_list_show_read_and_write_a_key_held_by_another_client(ixm_socket: str) -> None:
    with IxmClient(ixm_socket, name="holder") as holder:
        holder.open("/arm/joints", "float64", count=3, mode="w").write([1.0, 2.0, 3.0])
        assert mros(ixm_socket, "list") == (0, "/arm/joints  float64[3]  24 B  readers: 0  writers: 1\n")
        code, out = mros(ixm_socket, "show", "/arm/joints")
        assert code == 0 and "type: float64[3]" in out and "(holder)" in out
        assert mros(ixm_socket, "read", "/arm/joints") == (0, "[1.0, 2.0, 3.0]\n")
        assert mros(ixm_socket, "write", "/arm/joints", "[4, 5, 6]") == (0, "")
        assert mros(ixm_socket, "read", "/arm/joints") == (0, "[4.0, 5.0, 6.0]\n")


def test_a_message_key_is_written_from_yaml_and_read_as_rostopic_echo_prints_it(ixm_socket: str) -> None:
    with IxmClient(ixm_socket) as holder:
        holder.open("/v", "std_msgs/Float64", mode="r")
        assert mros(ixm_socket, "write", "/v", "{data: 2.5}") == (0, "")
        assert mros(ixm_socket, "read", "/v") == (0, "data: 2.5\n")


def test_read_follow_is_woken_by_each_write(ixm_socket: str) -> None:
    with IxmClient(ixm_socket) as holder:
        key = holder.open("/n", "int32", mode="w")
        key.write(1)
        # a process of its own, so that the write waits for the first value printed: a write between the
        # follower's open and its first read supersedes 1 (the registry keeps the latest value), as it did
        # when a loaded machine paused the follower there
        cmd = [sys.executable, "-m", "mros_cli.main", "ixm", "--socket", ixm_socket, "read", "/n", "-f", "-n", "2"]
        with subprocess.Popen([*cmd, "--timeout", "10"], stdout=subprocess.PIPE, text=True) as follower:
            try:
                assert follower.stdout is not None
                first = follower.stdout.readline()  # bounded: the follower gives up after 10 s
                first += follower.stdout.readline()  # its "---" (communicate reads past this file's buffer)
                key.write(2)
                rest, _ = follower.communicate(timeout=20)
            finally:
                follower.kill()
        assert (follower.returncode, first + rest) == (0, "1\n---\n2\n---\n")


def test_errors_are_one_line_with_exit_code_1(ixm_socket: str, tmp_path: object) -> None:
    code, out = mros(ixm_socket, "read", "/missing")
    assert code == 1 and "does not exist yet" in out
    code, out = mros(ixm_socket, "write", "/x", "1", "--type", "nope")
    assert code == 1 and "unknown type 'nope'" in out
    code, out = mros(f"{tmp_path}/none.sock", "list")
    assert code == 1 and "cannot reach the IXM daemon" in out
