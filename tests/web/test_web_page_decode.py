"""The page decodes ROS 1 bodies in the browser from the advertised definition: its decoder (static/ros1.js,
run under node) against mrosd's own serializer, over types with nesting, constants, fixed and variable
arrays, strings, time and duration, and truncated bodies (a typed error, never a hang or garbage). Its
serializer (what the service form sends) must give back the very bytes."""

from __future__ import annotations

import array
import base64
import json
import math
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from mrosd.msg import get_message_class

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="node is missing (scripts/install-system-deps.sh)")


def plain(value: Any) -> Any:
    """A deserialized mrosd message as the JSON the page's decoder gives (time as {secs, nsecs})."""
    if hasattr(type(value), "_slot_types"):
        return {slot: plain(getattr(value, slot)) for slot in type(value).__slots__}
    if hasattr(value, "secs") and hasattr(value, "nsecs"):
        return {"secs": value.secs, "nsecs": value.nsecs}
    if isinstance(value, bytes | bytearray):
        return list(value)
    if isinstance(value, list | tuple | array.array):
        return [plain(v) for v in value]
    return value


def decode_in_node(cases: list[tuple[type[Any], bytes]]) -> list[dict[str, Any]]:
    payload = [
        {"type": cls._type, "definition": cls._full_text, "body": base64.b64encode(body).decode()}
        for cls, body in cases
    ]
    assert NODE is not None
    done = subprocess.run(
        [NODE, str(HERE / "page_decode.mjs")],
        check=False,
        input=json.dumps(payload).encode(),
        capture_output=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr.decode()
    result: list[dict[str, Any]] = json.loads(done.stdout)
    return result


def close(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b)) or math.isclose(a, b, rel_tol=1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k]) for k in a)
    return bool(a == b)


def samples() -> list[Any]:
    m = get_message_class
    scan = m("sensor_msgs/LaserScan")(angle_min=-1.5, angle_max=1.5, ranges=[0.5, 1.25, 8.0], intensities=[1.0])
    scan.header.frame_id = "laser"
    scan.header.stamp.secs, scan.header.stamp.nsecs = 1700000000, 123456789
    image = m("sensor_msgs/Image")(height=2, width=3, encoding="rgb8", step=9, data=bytes(range(18)))
    cloud = m("sensor_msgs/PointCloud2")(
        height=1,
        width=2,
        fields=[m("sensor_msgs/PointField")(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
        point_step=12,
        row_step=24,
        data=bytes(range(24)),
        is_dense=True,
    )
    log = m("rosgraph_msgs/Log")(
        level=4, name="/n", msg="héllo ✓", file="f.py", function="g", line=7, topics=["/a", "/b"]
    )
    info = m("sensor_msgs/CameraInfo")(width=640, height=480, distortion_model="plumb_bob", D=[0.1, -0.2])
    info.K = [float(i) for i in range(9)]
    marker = m("visualization_msgs/Marker")(ns="ns", id=-3, type=2, text="t")
    marker.lifetime.secs, marker.lifetime.nsecs = -2, 500
    marker.points = [m("geometry_msgs/Point")(x=1.0, y=2.0, z=3.0)]
    markers = m("visualization_msgs/MarkerArray")(markers=[marker, marker])
    multi = m("std_msgs/Int64MultiArray")(data=[-(2**52), 0, 2**52])
    multi.layout.dim = [m("std_msgs/MultiArrayDimension")(label="x", size=3, stride=3)]
    return [scan, image, cloud, log, info, markers, multi, m("std_msgs/Bool")(data=True)]


def test_the_page_decodes_what_mrosd_serializes() -> None:
    msgs = samples()
    cases = [(type(msg), msg.serialize()) for msg in msgs]
    for (cls, body), got in zip(cases, decode_in_node(cases), strict=True):
        want = plain(cls.deserialize(body))
        assert "error" not in got, (cls._type, got)
        assert close(got["value"], want), (cls._type, got["value"], want)
        assert base64.b64decode(got["again"]) == body, cls._type  # the service form's serializer: the inverse


def test_a_truncated_or_lying_body_is_a_decode_error() -> None:
    scan = samples()[0]
    body = scan.serialize()
    cls = type(scan)
    lying = bytearray(get_message_class("std_msgs/String")(data="abc").serialize())
    lying[0:4] = (2**31).to_bytes(4, "little")  # a string length far beyond the body
    huge_array = (2**31).to_bytes(4, "little")  # Int64MultiArray's layout.dim count: 2^31 entries, no bytes
    cases = [(cls, body[:n]) for n in (0, 5, 20, len(body) - 1)]
    cases += [(get_message_class("std_msgs/String"), bytes(lying))]
    cases += [(get_message_class("std_msgs/Int64MultiArray"), huge_array)]
    for got in decode_in_node(cases):
        assert "DecodeError" in got.get("error", ""), got
