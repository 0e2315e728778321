"""Hostile input to ``mros bag convert``: a truncated bag, a record whose length lies, a damaged rosbag2 and CDR
bodies whose lengths lie. Each is one clear error (or one problem line for a bad body), never a traceback or a
huge allocation, and no half-written output is left under the output name."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from click.testing import CliRunner
from mros_cli.main import cli

from mrosd.bag.files import Rosbag1FileWriter
from mrosd.bag.model import BagError, ConnectionInfo
from mrosd.msg import get_message_class
from mrosd.ros2.bagconvert import convert_bag

String = get_message_class("std_msgs/String")


@pytest.fixture
def good_bag(tmp_path: Path) -> Path:
    path = tmp_path / "good.bag"
    w = Rosbag1FileWriter(str(path))
    conn = w.add_connection(ConnectionInfo("/chatter", String._type, String._md5sum, str(String._full_text)))
    for i in range(200):
        w.write(conn, 1_000 + i, String(data=f"message {i} " + "x" * 100).serialize())
    w.close()
    return path


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset of the data length field, header op, data length) of each top-level rosbag v2 record."""
    out, pos = [], len(b"#ROSBAG V2.0\n")
    while pos + 4 <= len(data):
        (hlen,) = struct.unpack_from("<I", data, pos)
        header = data[pos + 4 : pos + 4 + hlen]
        op = header[header.index(b"op=") + 3]
        dpos = pos + 4 + hlen
        (dlen,) = struct.unpack_from("<I", data, dpos)
        out.append((dpos, op, dlen))
        pos = dpos + 4 + dlen
    return out


def _cli_fails_with_one_line(args: list[str], says: str) -> None:
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 1, result.output
    assert says in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output


def test_a_truncated_bag_is_one_error_and_leaves_no_output(good_bag: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.bag"
    cut.write_bytes(good_bag.read_bytes()[: good_bag.stat().st_size * 2 // 3])
    out = tmp_path / "out"
    _cli_fails_with_one_line(["bag", "convert", str(cut), str(out), "--to", "ros2"], "cut.bag")
    assert not out.exists()


def test_a_message_record_whose_length_lies_midway_is_one_error_and_the_partial_output_is_removed(
    good_bag: Path, tmp_path: Path
) -> None:
    data = bytearray(good_bag.read_bytes())
    chunk = next(dpos for dpos, op, _dlen in _records(bytes(data)) if op == 0x05)
    # inside the (uncompressed) chunk: records of connection headers and messages; lie in the 150th message's
    pos, seen = chunk + 4, 0
    while True:
        (hlen,) = struct.unpack_from("<I", data, pos)
        header = bytes(data[pos + 4 : pos + 4 + hlen])
        dpos = pos + 4 + hlen
        if header[header.index(b"op=") + 3] == 0x02:
            seen += 1
            if seen == 150:
                struct.pack_into("<I", data, dpos, 0x7FFFFFF0)
                break
        pos = dpos + 4 + struct.unpack_from("<I", data, dpos)[0]
    liar = tmp_path / "liar.bag"
    liar.write_bytes(bytes(data))
    out = tmp_path / "out"
    seen_progress: list[int] = []
    with pytest.raises(BagError, match=r"liar\.bag"):
        convert_bag(str(liar), str(out), to="ros2", progress=lambda done, _total: seen_progress.append(done))
    assert not out.exists()


def test_a_damaged_rosbag2_is_one_error_and_leaves_no_output(good_bag: Path, tmp_path: Path) -> None:
    ros2 = tmp_path / "ros2"
    convert_bag(str(good_bag), str(ros2), to="ros2")
    mcap = next(ros2.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    back = tmp_path / "back.bag"
    _cli_fails_with_one_line(["bag", "convert", str(ros2), str(back), "--to", "ros1"], "ros2")
    assert not back.exists() and not Path(str(back) + ".active").exists()


def test_cdr_bodies_whose_lengths_lie_are_skipped_each_with_a_line(tmp_path: Path) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    ros2 = tmp_path / "lying_cdr"
    with Writer(ros2, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        w.write(conn, 1, b"\x00\x01\x00\x00" + struct.pack("<I", 6) + b"hello\x00")
        w.write(conn, 2, b"\x00\x01\x00\x00" + struct.pack("<I", 0x7FFFFFF0) + b"hello\x00")
        w.write(conn, 3, b"\x00\x01\x00\x00" + struct.pack("<I", 3) + b"ok\x00")
    report = convert_bag(str(ros2), str(tmp_path / "back.bag"), to="ros1")
    assert (report.written, report.skipped) == (2, 1)
    assert len(report.problems) == 1 and "/chatter at 2 ns" in report.problems[0]


def test_an_existing_output_is_refused_and_kept(good_bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "taken.bag"
    out.write_bytes(b"mine")
    with pytest.raises(BagError, match="exists already"):
        convert_bag(str(good_bag), str(out), to="ros1")
    assert out.read_bytes() == b"mine"
