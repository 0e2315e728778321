"""`mros service type/call` against a rospy service server give what rosservice gives."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, ros_tool, start_rospy
from tests.rosenv import Processes, needs_ros

pytestmark = [needs_ros, pytest.mark.interop]

SERVER = """
import rospy
from std_srvs.srv import SetBool, SetBoolResponse, Trigger, TriggerResponse, Empty, EmptyResponse
rospy.init_node("srv")
rospy.Service("/set", SetBool, lambda r: SetBoolResponse(success=r.data, message="got %s" % r.data))
rospy.Service("/trigger", Trigger, lambda r: TriggerResponse(success=True, message="fired"))
rospy.Service("/empty", Empty, lambda r: EmptyResponse())
print("up", flush=True)
rospy.spin()
"""


@pytest.fixture
def server(procs: Processes, rosmaster: str) -> str:
    start_rospy(procs, SERVER, rosmaster)
    return rosmaster


def test_service_type_and_uri_match_rosservice(server: str, tmp_path: Path) -> None:
    for argv in (["type", "/set"], ["type", "/trigger"], ["uri", "/set"]):
        ours = mros(server, tmp_path, "service", *argv)
        theirs = ros_tool(server, tmp_path, "rosservice", *argv)
        assert (ours.returncode, ours.stdout) == (theirs.returncode, theirs.stdout), argv
    missing = mros(server, tmp_path, "service", "type", "/nope")
    assert missing.returncode == 1
    assert missing.stderr == "Unknown service [/nope]\n"


def test_service_call_prints_the_response_as_rosservice(server: str, tmp_path: Path) -> None:
    for argv in (["/set", "{data: true}"], ["/set", "false"], ["/trigger"], ["/empty"]):
        ours = mros(server, tmp_path, "service", "call", *argv)
        theirs = ros_tool(server, tmp_path, "rosservice", "call", *argv)
        assert ours.returncode == theirs.returncode == 0, (argv, ours.stderr)
        assert ours.stdout == theirs.stdout, argv


def test_a_wrong_request_field_is_a_one_line_error(server: str, tmp_path: Path) -> None:
    out = mros(server, tmp_path, "service", "call", "/set", "{dta: 1}")
    theirs = ros_tool(server, tmp_path, "rosservice", "call", "/set", "{dta: 1}")
    assert out.returncode == theirs.returncode == 2  # rosservice's code for arguments it cannot use
    # rosservice: "ERROR: Incompatible arguments to call service:\nNo field name [dta]\n...\n\n"
    # "Service arguments are: [data]"; mros names the field and the type in one line, then the same hint
    assert out.stderr == (
        "ERROR: field dta: std_srvs/SetBoolRequest has no such field; its fields are: data\n\n"
        "Service arguments are: [data]\n"
    )
