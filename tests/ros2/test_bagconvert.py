"""``mros bag convert``: a rosbag v2 with standard, latched and custom types -> rosbag2 (MCAP, sqlite3) -> rosbag v2.

The rosbag2 is read back by mcap's own reader (container, channels, schemas) with hashes checked against
ros2-pyterfaces; the bag that comes back is read by Debian's rosbag (``rosbag info`` and its Python API, which
decodes every message from the bag's definitions with genpy): bodies are byte-identical but for Header.seq.
"""

from __future__ import annotations

import os
import struct
import subprocess
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from mros_cli.main import cli

from mrosd.bag.files import Rosbag1FileWriter, open_bag
from mrosd.bag.model import ConnectionInfo
from mrosd.msg import get_message_class, load_type
from mrosd.ros2.bagconvert import convert_bag
from tests.rosenv import ros_available

ROUTE_1 = """std_msgs/Header header
fleet_msgs/Waypoint[] points
int32[3] tags
bool done
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: fleet_msgs/Waypoint
uint8 KIND_GOAL=1
string name
float64 x
duration wait
"""
STRINGS = 1100  # over the progress step, so progress is shown more than once


def _bodies(path: str) -> dict[str, list[tuple[int, bytes]]]:
    reader = open_bag(path)
    try:
        out: dict[str, list[tuple[int, bytes]]] = {}
        for info, t_ns, data in reader.messages():
            out.setdefault(info.topic, []).append((t_ns, bytes(data)))
        return out
    finally:
        reader.close()


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The input bag, its rosbag2 (through the CLI, progress on) and the bag converted back."""
    tmp = tmp_path_factory.mktemp("convert")
    String, Image = get_message_class("std_msgs/String"), get_message_class("sensor_msgs/Image")
    Route = load_type("fleet_msgs/Route", ROUTE_1)
    Waypoint = load_type("fleet_msgs/Waypoint", ROUTE_1.split("MSG: fleet_msgs/Waypoint\n")[1])
    src = str(tmp / "in.bag")
    w = Rosbag1FileWriter(src)

    def conn(topic: str, cls: Any, latch: bool = False) -> Any:
        return w.add_connection(ConnectionInfo(topic, cls._type, cls._md5sum, str(cls._full_text), "/rec", latch))

    chatter, img_conn, map_conn, route_conn = (
        conn("/chatter", String),
        conn("/camera", Image),
        conn("/map", String, True),
        conn("/route", Route),
    )
    for i in range(STRINGS):
        w.write(chatter, 1_000_000_000 + i * 1000, String(data=f"hello {i}").serialize())
    img = Image(height=480, width=640, encoding="rgb8", step=1920, data=os.urandom(640 * 480 * 3))
    img.header.frame_id = "cam"
    for i in range(3):
        img.header.seq, img.header.stamp.secs = 100 + i, i  # the publisher's counter: ROS 2 has no place for it
        w.write(img_conn, 2_000_000_000 + i, img.serialize())
    w.write(map_conn, 3_000_000_000, String(data="the map").serialize())
    route = Route(points=[Waypoint(name="a", x=1.5), Waypoint(name="b", x=-2.0)], tags=[1, 2, 3], done=True)
    route.header.frame_id, route.points[1].wait.secs = "odom", 7
    w.write(route_conn, 4_000_000_000, route.serialize())
    w.close()
    ros2 = str(tmp / "out_ros2")
    result = CliRunner().invoke(cli, ["bag", "convert", src, ros2, "--to", "ros2", "--progress"])
    assert result.exit_code == 0, result.output
    back = str(tmp / "back.bag")
    convert_bag(ros2, back, to="ros1")
    return {"src": src, "ros2": ros2, "back": back, "tmp": tmp, "cli": result, "route_md5": Route._md5sum}


def test_the_rosbag2_reads_with_mcaps_reader_with_ros2_types_and_rmw_zenohs_hashes(bags: dict[str, Any]) -> None:
    from mcap.reader import make_reader

    assert f"{STRINGS + 5}/{STRINGS + 5} messages (100%)" in bags["cli"].output  # progress, on stderr
    with (Path(bags["ros2"]) / "out_ros2.mcap").open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        types = {t: summary.schemas[c.schema_id].name for t, c in channels.items()}
        assert types == {
            "/chatter": "std_msgs/msg/String",
            "/camera": "sensor_msgs/msg/Image",
            "/map": "std_msgs/msg/String",
            "/route": "fleet_msgs/msg/Route",
        }
        assert all(c.message_encoding == "cdr" for c in channels.values())
        assert "transient_local" in channels["/map"].metadata["offered_qos_profiles"]
        first = next(m for _s, c, m in reader.iter_messages(topics=["/chatter"]))
    assert first.data == b"\x00\x01\x00\x00" + struct.pack("<I", 8) + b"hello 0\x00"
    meta = (Path(bags["ros2"]) / "metadata.yaml").read_text()
    assert "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18" in meta  # std_msgs/String
    core: Any = pytest.importorskip("ros2_pyterfaces.core")
    time_ = {"__typename": "builtin_interfaces/msg/Time", "sec": "int32", "nanosec": "uint32"}
    waypoint = {
        "__typename": "fleet_msgs/msg/Waypoint",
        "name": "string",
        "x": "float64",
        "wait": {"__typename": "builtin_interfaces/msg/Duration", "sec": "int32", "nanosec": "uint32"},
    }
    route = {
        "__typename": "fleet_msgs/msg/Route",
        "header": {"__typename": "std_msgs/msg/Header", "stamp": time_, "frame_id": "string"},
        "points": core.Sequence(waypoint),
        "tags": core.Array("int32", 3),
        "done": "bool",
    }
    # the constant KIND_GOAL takes part in RIHS01 in rosidl but not in ros2-pyterfaces' schema: compare without it
    from mrosd.ros2.types import TypeMapper

    no_const = ROUTE_1.replace("uint8 KIND_GOAL=1\n", "")
    assert TypeMapper().mapping("fleet_msgs/Route", no_const).type_hash == core.hash_rihs01(route)


def test_the_bag_converted_back_has_the_same_bodies_but_header_seq(bags: dict[str, Any]) -> None:
    before, after = _bodies(bags["src"]), _bodies(bags["back"])
    assert set(before) == set(after)
    for topic in ("/chatter", "/map"):
        assert after[topic] == before[topic]
    for (t0, b0), (t1, b1), seq in zip(before["/camera"], after["/camera"], range(3), strict=True):
        assert t0 == t1 and struct.unpack_from("<I", b1)[0] == seq and b1[4:] == b0[4:]
    assert after["/route"][0][1][4:] == before["/route"][0][1][4:]
    reader = open_bag(bags["back"])
    try:
        conns = {c.topic: c for c in reader.connections}
    finally:
        reader.close()
    assert conns["/map"].latching and not conns["/chatter"].latching
    assert conns["/route"].type == "fleet_msgs/Route" and conns["/route"].md5sum == bags["route_md5"]
    assert conns["/camera"].md5sum == get_message_class("sensor_msgs/Image")._md5sum


@pytest.mark.skipif(not ros_available(), reason="Debian's ROS 1 (rosbag) is not installed")
def test_debians_rosbag_reads_and_decodes_the_bag_converted_back(bags: dict[str, Any]) -> None:
    info = subprocess.run(["rosbag", "info", bags["back"]], capture_output=True, timeout=60, check=True)
    text = info.stdout.decode()
    assert f"fleet_msgs/Route  [{bags['route_md5']}]" in text and f"{STRINGS} msgs" in text
    script = (
        "import rosbag, sys\n"
        "b = rosbag.Bag(sys.argv[1])\n"
        "for topic, msg, t in b.read_messages(topics=['/route', '/map']):\n"
        "    print(topic, msg.header.frame_id if topic == '/route' else msg.data,"
        " [(p.name, p.x, p.wait.secs) for p in msg.points] if topic == '/route' else '')\n"
    )
    out = subprocess.run(["/usr/bin/python3", "-c", script, bags["back"]], check=False, capture_output=True, timeout=60)
    assert out.returncode == 0, out.stderr.decode()
    assert out.stdout.decode().splitlines() == ["/map the map ", "/route odom [('a', 1.5, 0), ('b', -2.0, 7)]"]


def test_sqlite3_storage_converts_both_ways_too(bags: dict[str, Any]) -> None:
    out = str(bags["tmp"] / "out_sqlite")
    report = convert_bag(bags["src"], out, to="ros2", storage="sqlite3")
    assert report.written == STRINGS + 5 and not report.problems
    assert any(p.suffix == ".db3" for p in Path(out).iterdir())
    back = str(bags["tmp"] / "back_sqlite.bag")
    convert_bag(out, back, to="ros1")
    assert _bodies(back)["/chatter"] == _bodies(bags["src"])["/chatter"]


def test_a_type_that_cannot_cross_is_one_line_and_the_other_topics_convert(tmp_path: Path) -> None:
    String = get_message_class("std_msgs/String")
    src = str(tmp_path / "mixed.bag")
    w = Rosbag1FileWriter(src)
    ok = w.add_connection(ConnectionInfo("/ok", String._type, String._md5sum, str(String._full_text)))
    bad = w.add_connection(ConnectionInfo("/bad", "robot/State", "0" * 32, "float32 batteryLevel\n"))
    w.write(ok, 1, String(data="x").serialize())
    w.write(bad, 2, struct.pack("<f", 0.5))
    w.close()
    report = convert_bag(src, str(tmp_path / "mixed2"), to="ros2")
    assert (report.written, report.skipped) == (1, 1)
    assert len(report.problems) == 1 and "/bad" in report.problems[0] and "batteryLevel" in report.problems[0]


def test_a_service_event_topic_of_a_rosbag2_is_one_line_and_the_others_convert(tmp_path: Path) -> None:
    """``ros2 bag record --all-services`` topics (``pkg/srv/X_Event``, holding ``service_msgs/ServiceEventInfo``
    whose ``char[16]`` rosbags hashes differently from rosidl) have no ROS 1 type: skipped, never half-converted."""
    from rosbags.rosbag2 import Writer

    from mrosd.ros2.srvtypes import service_mapping
    from mrosd.ros2.types import TypeMapper

    store = TypeMapper().store
    setbool = service_mapping(TypeMapper(), "std_srvs/SetBool", "bool data\n", "bool success\n")
    event = setbool.ros2_type + "_Event"
    src = tmp_path / "events"
    with Writer(src, version=9) as w:
        ev = w.add_connection("/set_flag/_service_event", event, msgdef="bool data\n", rihs01=setbool.type_hash)
        ok = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        w.write(ev, 1, b"\x00\x01\x00\x00" + bytes(40))
        w.write(ok, 2, store.serialize_cdr(store.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
    report = convert_bag(str(src), str(tmp_path / "back.bag"), to="ros1")
    assert (report.written, report.skipped) == (1, 1)
    assert len(report.problems) == 1 and "/set_flag/_service_event" in report.problems[0]


@pytest.mark.skipif(not ros_available(), reason="Debian's ROS 1 (rosbag) is not installed")
async def test_debians_rosbag_play_serves_the_bag_converted_back(
    bags: dict[str, Any], procs: Any, rosmaster: str, tmp_path: Path
) -> None:
    import asyncio

    import mrosd
    from mrosd import backports
    from tests.rosenv import ros_env

    Route = load_type("fleet_msgs/Route", ROUTE_1)
    got: asyncio.Queue[Any] = asyncio.Queue(maxsize=1)
    async with mrosd.Node("bag_listener", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        # the md5 rosbag play offers is the bag's: the handshake passes only if it is genmsg's for ROUTE_1
        await node.subscribe("/route", Route, callback=lambda m: got.full() or got.put_nowait(m))
        env = ros_env(rosmaster, tmp_path)
        echo = procs.start(["rostopic", "echo", "-n", "1", "/map"], env)
        procs.start(["rosbag", "play", "-q", "-d", "1", bags["back"]], env)
        route = await backports.wait_for(got.get(), 60)
        out, err = await asyncio.to_thread(echo.communicate, timeout=60)
    assert route.header.frame_id == "odom" and [p.name for p in route.points] == ["a", "b"]
    assert b"the map" in out, err
