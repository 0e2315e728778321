"""Messages from a real rospy publisher decode with classes built from its connection header alone.

The test speaks just enough TCPROS itself (stdlib sockets, bounded by timeouts) to stay independent of
mrosd.tcpros: it asks the real rosmaster for the publisher, connects with md5 and type ``*``, builds the
class with ``load_type`` from the header's message_definition and checks md5 and field values, for a
standard type and for a user-defined type rospy generated at run time (arrays of it included).
"""

from __future__ import annotations

import socket
import struct
import xmlrpc.client
from collections.abc import Iterator
from typing import Any

import pytest

from mrosd.msg import get_message_class, load_type
from tests.rosenv import Processes, iter_lines_until, needs_ros, ros_env

pytestmark = needs_ros

COORDINATE = "float32 x\nfloat32 y\nfloat32 z\ntime time\n"
TRACK = "Header header\nmros_test_msgs/Coordinate[] points\nstring name\n"

TALKER = f"""
import rospy, genpy.dynamic
from geometry_msgs.msg import PoseStamped
SEP = "=" * 80
HEADER = open("/usr/share/std_msgs/msg/Header.msg").read()
track_text = {TRACK!r} + "\\n" + SEP + "\\nMSG: std_msgs/Header\\n" + HEADER \\
    + "\\n" + SEP + "\\nMSG: mros_test_msgs/Coordinate\\n" + {COORDINATE!r}
Track = genpy.dynamic.generate_dynamic("mros_test_msgs/Track", track_text)["mros_test_msgs/Track"]
Coordinate = genpy.dynamic.generate_dynamic("mros_test_msgs/Coordinate", {COORDINATE!r})["mros_test_msgs/Coordinate"]
rospy.init_node("wire_talker")
pose = rospy.Publisher("/pose", PoseStamped, queue_size=10, latch=True)
track = rospy.Publisher("/track", Track, queue_size=10, latch=True)
p = PoseStamped()
p.header.seq, p.header.stamp, p.header.frame_id = 7, rospy.Time(1700000000, 5), "map/é"
p.pose.position.x, p.pose.orientation.w = 1.5, 1.0
pose.publish(p)
t = Track()
t.header.frame_id = "odom"
t.name = "path ✓"
t.points = [Coordinate(1.0, 2.0, 3.0, rospy.Time(1, 2)), Coordinate(-1.0, 0.5, 0.25, rospy.Time(3, 4))]
track.publish(t)
print("ready", flush=True)
rospy.spin()
"""


def encode_header(fields: dict[str, str]) -> bytes:
    body = b"".join(
        struct.pack("<I", len(k) + 1 + len(v.encode())) + f"{k}=".encode() + v.encode() for k, v in fields.items()
    )
    return struct.pack("<I", len(body)) + body


def read_exactly(sock: socket.socket, size: int) -> bytes:
    chunks = bytearray()
    while len(chunks) < size:
        chunk = sock.recv(size - len(chunks))
        if not chunk:
            raise EOFError(f"connection closed after {len(chunks)} of {size} bytes")
        chunks += chunk
    return bytes(chunks)


def read_header(sock: socket.socket) -> dict[str, str]:
    (size,) = struct.unpack("<I", read_exactly(sock, 4))
    body = read_exactly(sock, size)
    fields: dict[str, str] = {}
    at = 0
    while at < len(body):
        (length,) = struct.unpack_from("<I", body, at)
        key, _, value = body[at + 4 : at + 4 + length].decode().partition("=")
        fields[key] = value
        at += 4 + length
    return fields


@pytest.fixture
def talker(rosmaster: str, procs: Processes) -> Iterator[str]:
    proc = procs.python(TALKER, ros_env(rosmaster, procs.tmp))
    assert list(iter_lines_until(proc, 1, timeout=60)) == ["ready"]
    yield rosmaster


def subscribe_raw(master_uri: str, topic: str) -> tuple[dict[str, str], bytes]:
    """Connect to ``topic``'s publisher with md5/type ``*``; return its header and the first frame."""
    with xmlrpc.client.ServerProxy(master_uri) as master:
        code, status, publishers = master.registerSubscriber("/mros_wire_test", topic, "*", "http://127.0.0.1:9/")
    assert code == 1 and publishers, status
    with xmlrpc.client.ServerProxy(publishers[0]) as node:
        code, status, protocol = node.requestTopic("/mros_wire_test", topic, [["TCPROS"]])
    assert code == 1, status
    _, host, port = protocol
    with socket.create_connection((host, port), timeout=10) as sock:
        sock.settimeout(10)
        sock.sendall(encode_header({"callerid": "/mros_wire_test", "topic": topic, "md5sum": "*", "type": "*"}))
        header = read_header(sock)
        assert "error" not in header, header
        (size,) = struct.unpack("<I", read_exactly(sock, 4))
        return header, read_exactly(sock, size)


def decode(header: dict[str, str], frame: bytes) -> Any:
    cls = load_type(header["type"], header["message_definition"])
    assert cls._md5sum == header["md5sum"]
    msg = cls.deserialize(frame)
    assert msg.serialize() == frame
    return msg


def test_a_standard_message_decodes_from_the_publishers_definition(talker: str) -> None:
    header, frame = subscribe_raw(talker, "/pose")
    msg = decode(header, frame)
    assert header["md5sum"] == get_message_class("geometry_msgs/PoseStamped")._md5sum
    assert header["message_definition"] == get_message_class("geometry_msgs/PoseStamped")._full_text
    # rospy numbers the header itself (seq 1 for the first message), whatever seq the caller set.
    assert (msg.header.seq, msg.header.stamp.secs, msg.header.stamp.nsecs) == (1, 1_700_000_000, 5)
    assert msg.header.frame_id == "map/é"
    assert (msg.pose.position.x, msg.pose.orientation.w) == (1.5, 1.0)


def test_a_user_type_with_an_array_of_user_types_decodes_without_any_files(talker: str) -> None:
    header, frame = subscribe_raw(talker, "/track")
    msg = decode(header, frame)
    assert header["type"] == "mros_test_msgs/Track"
    assert msg.name == "path ✓"
    assert msg.header.frame_id == "odom"
    assert [(p.x, p.y, p.z, p.time.secs, p.time.nsecs) for p in msg.points] == [
        (1.0, 2.0, 3.0, 1, 2),
        (-1.0, 0.5, 0.25, 3, 4),
    ]
    assert type(msg.points[0])._fixed_size == 20
