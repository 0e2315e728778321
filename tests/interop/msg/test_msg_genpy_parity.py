"""mrosd.msg against Debian's genmsg/genpy: every md5 and definition text, and serialized bytes.

The oracle (genpy_oracle.py) runs under the system interpreter, which has genmsg, genpy and the
generated message packages; this side never imports them.
"""

from __future__ import annotations

import json
import subprocess
from array import array
from pathlib import Path
from typing import Any

import pytest

from mrosd.msg import Duration, Time, get_message_class
from mrosd.msg.typestore import BUILTIN_DIR, TypeStore
from tests.rosenv import ROS_PYTHON, needs_ros

ORACLE = Path(__file__).with_name("genpy_oracle.py")

pytestmark = needs_ros


def oracle(command: str, payload: Any = None) -> Any:
    proc = subprocess.run(
        [ROS_PYTHON, str(ORACLE), command],
        input=json.dumps(payload) if payload is not None else "",
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.fixture(scope="module")
def genmsg_table() -> dict[str, dict[str, str]]:
    table: dict[str, dict[str, str]] = oracle("md5")
    assert len(table) > 100
    return table


@pytest.fixture(scope="module")
def genpy_classes() -> dict[str, dict[str, Any]]:
    classes: dict[str, dict[str, Any]] = oracle("classes")
    assert "std_msgs/String" in classes
    return classes


def test_every_debian_message_and_service_has_genmsg_md5_and_full_text(
    genmsg_table: dict[str, dict[str, str]],
) -> None:
    store = TypeStore(builtin=False, ros_package_path="", system_dirs=["/usr/share"])
    mismatches = []
    for key, expected in genmsg_table.items():
        assert "error" not in expected, (key, expected)
        kind, name = key.split(":")
        if kind == "msg":
            got = {"md5": store.md5(name), "full_text": store.full_text(name)}
        else:
            srv = store.srv_spec(name)
            got = {
                "md5": store.srv_md5(name),
                "request_md5": store.md5(srv.request.full_name),
                "response_md5": store.md5(srv.response.full_name),
                "request_full_text": store.full_text(srv.request.full_name),
                "response_full_text": store.full_text(srv.response.full_name),
            }
        if got != expected:
            mismatches.append(key)
    assert mismatches == []


def test_shipped_definitions_are_verbatim_copies_of_debians(genmsg_table: dict[str, dict[str, str]]) -> None:
    shipped = sorted(BUILTIN_DIR.glob("*/*/*.*"))
    assert len(shipped) > 150
    for path in shipped:
        if path.suffix not in (".msg", ".srv"):
            continue
        if path.relative_to(BUILTIN_DIR).parts[0] == "roscpp":
            # Debian ships roscpp's logger types only as generated Python; tests/interop/tcpros compares them
            # with genpy's classes instead (test_the_roscpp_logger_types_match_genpys).
            continue
        if path.relative_to(BUILTIN_DIR).parts[0] == "rosapi":
            # rosapi's definitions come from rosbridge_suite (ros1 branch), which Debian does not package;
            # tests/web/test_web_rosbridge_rosapi.py checks the services answer under those types.
            continue
        if path.relative_to(BUILTIN_DIR).parts[0] == "tf2_web_republisher":
            # not packaged by Debian either; tests/unit/tf/test_tf_republish.py holds genmsg's md5s.
            continue
        original = Path("/usr/share") / path.relative_to(BUILTIN_DIR)
        assert path.read_bytes() == original.read_bytes(), path


def test_builtin_classes_match_genpy_classes(genpy_classes: dict[str, dict[str, Any]]) -> None:
    for name, expected in genpy_classes.items():
        cls = get_message_class(name)
        assert (cls._md5sum, cls._full_text, cls._has_header) == (
            expected["md5"],
            expected["full_text"],
            expected["has_header"],
        ), name


def test_genpy_bytes_decode_and_reencode_identically_for_every_type(
    genmsg_table: dict[str, dict[str, str]],
) -> None:
    names = sorted(key.split(":")[1] for key in genmsg_table if key.startswith("msg:"))
    samples = oracle("sample", names)
    assert len(samples) == 3 * len(names)
    ours = []
    for name, data in samples:
        body = bytes.fromhex(data)
        msg = get_message_class(name).deserialize(body)
        assert msg.serialize() == body, name
        ours.append([name, msg.serialize().hex()])
    assert oracle("reencode", ours) == [hexed for _, hexed in ours]


def corpus() -> list[Any]:
    """Hand-picked values: nested, arrays of messages, fixed/empty arrays, UTF-8, time, bytes, char/byte."""
    header = get_message_class("std_msgs/Header")
    point = get_message_class("geometry_msgs/Point32")
    field = get_message_class("sensor_msgs/PointField")
    return [
        get_message_class("std_msgs/String")(data="héllo wörld ✓ 日本語"),
        get_message_class("std_msgs/String")(data=""),
        get_message_class("std_msgs/Char")(data=255),
        get_message_class("std_msgs/Byte")(data=-128),
        get_message_class("std_msgs/Bool")(data=True),
        get_message_class("std_msgs/Int64")(data=-(2**63)),
        get_message_class("std_msgs/UInt64")(data=2**64 - 1),
        get_message_class("std_msgs/Float32")(data=1.5),
        get_message_class("std_msgs/Time")(data=Time(2**32 - 1, 999_999_999)),
        get_message_class("std_msgs/Duration")(data=Duration(-5, 10)),
        get_message_class("std_msgs/UInt8MultiArray")(data=b"\x00\x01\xff"),
        get_message_class("std_msgs/Float64MultiArray")(data=array("d", [1.0, -2.5, 1e300])),
        get_message_class("std_msgs/Int16MultiArray")(data=[1, -2, 3]),
        get_message_class("sensor_msgs/PointCloud")(
            header=header(seq=7, stamp=Time(1, 2), frame_id="map"),
            points=[point(x=1.0, y=2.0, z=3.0), point()],
        ),
        get_message_class("sensor_msgs/PointCloud2")(
            height=1, width=2, fields=[field(name="x", offset=0, datatype=7, count=1)], data=b"\x01" * 8
        ),
        get_message_class("sensor_msgs/CameraInfo")(K=[float(i) for i in range(9)], D=[0.5, 0.25]),
        get_message_class("sensor_msgs/JointState")(name=["a", "βeta", ""], position=[1.0, 2.0, 3.0]),
        get_message_class("diagnostic_msgs/DiagnosticArray")(status=[]),
        get_message_class("trajectory_msgs/JointTrajectory")(
            points=[get_message_class("trajectory_msgs/JointTrajectoryPoint")(time_from_start=Duration(1, 5))]
        ),
        get_message_class("visualization_msgs/MarkerArray")(markers=[get_message_class("visualization_msgs/Marker")()]),
    ]


def test_corpus_serializes_to_the_bytes_genpy_produces() -> None:
    messages = corpus()
    ours = [[m._type, m.serialize().hex()] for m in messages]
    assert oracle("reencode", ours) == [hexed for _, hexed in ours]
    for msg in messages:
        again = type(msg).deserialize(msg.serialize())
        assert again.serialize() == msg.serialize()
