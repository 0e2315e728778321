"""Bag files on disk: what the writers store is read back byte for byte; the writer thread's queue is bounded.

Real files through rosbags and mcap (no network). A damaged file is always a BagError, never another
exception or a crash.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrosd.bag.files import BagFileWriter, open_bag, open_writer
from mrosd.bag.model import BagError, ConnectionInfo, SplitPolicy
from mrosd.bag.recorder import RecordSink
from mrosd.wire.header import ConnectionHeader

STRING_MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"
STRING = ConnectionInfo("/chatter", "std_msgs/String", STRING_MD5, "string data\n", "/talker", latching=True)
INT32 = ConnectionInfo("/n", "std_msgs/Int32", "da5909fbe378aeaf85e547e830cc1bb7", "int32 data\n", "/counter")


def header(conn: ConnectionInfo) -> ConnectionHeader:
    return ConnectionHeader(
        callerid=conn.callerid,
        type=conn.type,
        md5sum=conn.md5sum,
        message_definition=conn.message_definition,
        latching="1" if conn.latching else "0",
    )


def string_body(text: str) -> bytes:
    data = text.encode()
    return len(data).to_bytes(4, "little") + data


@pytest.mark.parametrize(("fmt", "compression"), [("bag", "none"), ("bag", "bz2"), ("bag", "lz4"), ("mcap", "none"),
                                                  ("mcap", "zstd")])  # fmt: skip
def test_written_bytes_and_connections_read_back_unchanged(tmp_path: Path, fmt: str, compression: str) -> None:
    path = str(tmp_path / f"x.{fmt}")
    writer = open_writer(path, fmt, compression)
    a, b = writer.add_connection(STRING), writer.add_connection(INT32)
    sent = []
    for i in range(300):
        body = string_body(f"message {i}" * (i % 7))
        writer.write(a, 1_000_000_000 + i * 1000, body)
        sent.append((STRING, 1_000_000_000 + i * 1000, body))
        if i % 3 == 0:
            n = i.to_bytes(4, "little")
            writer.write(b, 1_000_000_000 + i * 1000 + 1, n)
            sent.append((INT32, 1_000_000_000 + i * 1000 + 1, n))
    writer.close()
    reader = open_bag(path)
    try:
        assert sorted(reader.connections, key=lambda c: c.topic) == [STRING, INT32]
        assert list(reader.messages()) == sent
        summary = reader.summary()
        assert summary.messages == len(sent)
        assert {t.topic: t.messages for t in summary.topics} == {"/chatter": 300, "/n": 100}
        assert summary.types == {"std_msgs/String": STRING_MD5, "std_msgs/Int32": INT32.md5sum}
        assert reader.start_ns == 1_000_000_000
        assert reader.end_ns == 1_000_000_000 + 299 * 1000
        assert list(reader.messages(start_ns=1_000_000_000 + 299 * 1000)) == sent[-1:]
    finally:
        reader.close()


def test_a_rosbag_is_written_as_active_and_renamed_when_complete(tmp_path: Path) -> None:
    path = tmp_path / "r.bag"
    writer = open_writer(str(path), "bag")
    assert (tmp_path / "r.bag.active").exists()
    assert not path.exists()
    writer.close()
    assert path.exists()
    assert not (tmp_path / "r.bag.active").exists()
    with pytest.raises(BagError, match="exists already"):
        open_writer(str(path), "bag")


def test_unreadable_or_foreign_files_are_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="cannot read"):
        open_bag(str(tmp_path / "missing.bag"))
    (tmp_path / "text.bag").write_text("hello\n")
    with pytest.raises(BagError, match="neither a rosbag"):
        open_bag(str(tmp_path / "text.bag"))
    (tmp_path / "unindexed.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(4096))
    with pytest.raises(BagError):
        open_bag(str(tmp_path / "unindexed.bag"))


@pytest.fixture(scope="module")
def sample_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    out = {}
    for fmt in ("bag", "mcap"):
        path = str(tmp_path_factory.mktemp("sample") / f"s.{fmt}")
        writer = open_writer(path, fmt)
        handle = writer.add_connection(STRING)
        for i in range(50):
            writer.write(handle, i, string_body("x" * i))
        writer.close()
        out[fmt] = Path(path).read_bytes()
    return out


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    fmt=st.sampled_from(["bag", "mcap"]),
    edits=st.lists(st.tuples(st.integers(9), st.binary(min_size=1, max_size=8)), min_size=1, max_size=6),
    cut=st.none() | st.integers(9),
)
def test_a_damaged_file_is_a_bag_error_and_nothing_else(
    tmp_path: Path, sample_files: dict[str, bytes], fmt: str, edits: list[tuple[int, bytes]], cut: int | None
) -> None:
    data = bytearray(sample_files[fmt])
    for offset, chunk in edits:
        pos = offset % len(data)
        data[pos : pos + len(chunk)] = chunk
    if cut is not None:
        data = data[: max(9, cut % len(data))]
    path = tmp_path / f"fuzz.{fmt}"
    path.write_bytes(bytes(data))
    try:
        reader = open_bag(str(path))
    except BagError:
        return
    try:
        reader.summary()
        for _ in reader.messages():
            pass
    except BagError:
        pass
    finally:
        reader.close()


# --- the writer thread ----------------------------------------------------------------------------------


class StalledDisk:
    """A BagFileWriter whose writes wait until ``release`` is set: a disk that cannot keep up."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.written = 0
        self.release = threading.Event()
        self.entered = threading.Event()
        self.bodies: list[bytes] = []

    def add_connection(self, conn: ConnectionInfo) -> Any:
        return conn

    def write(self, handle: Any, t_ns: int, data: bytes | bytearray | memoryview) -> None:
        self.entered.set()
        assert self.release.wait(10)
        self.bodies.append(bytes(data))
        self.written += len(data)

    def close(self) -> None:
        pass


def test_a_stalled_writer_never_blocks_put_and_the_oldest_messages_are_dropped_and_counted() -> None:
    disk = StalledDisk("stalled")
    sink = RecordSink(lambda i: disk, buffer_bytes=10_000)
    h = header(STRING)
    sink.put("/chatter", h, 1, b"first")
    assert disk.entered.wait(5)  # the thread holds "first" and waits on the disk
    started = time.monotonic()
    for i in range(100):
        sink.put("/chatter", h, 2 + i, i.to_bytes(1, "little") * 1000)  # 100 kB into a 10 kB buffer
    assert time.monotonic() - started < 5.0  # never waited for the disk (a put that waits would wait 10 s)
    # "first" (5 bytes) is held by the writer, so 9 of the 1000-byte messages fit: the newest 9.
    assert sink.stats.dropped == 91
    assert sink.held_bytes == 9_005
    disk.release.set()
    sink.close()
    assert disk.bodies == [b"first"] + [i.to_bytes(1, "little") * 1000 for i in range(91, 100)]
    assert (sink.stats.received, sink.stats.written) == (101, 10)
    assert sink.held_bytes == 0


def test_a_message_larger_than_the_whole_buffer_is_dropped_not_held() -> None:
    disk = StalledDisk("stalled")
    sink = RecordSink(lambda i: disk, buffer_bytes=1000)
    sink.put("/chatter", header(STRING), 1, bytes(600))
    assert disk.entered.wait(5)
    sink.put("/chatter", header(STRING), 2, bytes(600))  # 600 held by the writer + 600 > 1000
    assert (sink.stats.dropped, sink.held_bytes) == (1, 600)
    disk.release.set()
    sink.close()
    assert len(disk.bodies) == 1


def test_split_by_size_writes_numbered_files_that_together_hold_every_message(tmp_path: Path) -> None:
    stem = str(tmp_path / "run")
    sink = RecordSink(
        lambda i: open_writer(f"{stem}_{i}.bag", "bag"),
        buffer_bytes=0,
        split=SplitPolicy(max_bytes=50_000),
        splitting=True,
    )
    h = header(STRING)
    bodies = [string_body(str(i) * 1000)[: 1000 + i] for i in range(200)]
    for i, body in enumerate(bodies):
        sink.put("/chatter", h, 1_000 + i, body)
    sink.close()
    assert len(sink.stats.files) >= 4
    got = []
    for path in sink.stats.files:
        reader = open_bag(path)
        assert reader.connections == [STRING]  # every file is complete on its own
        got.extend(data for _c, _t, data in reader.messages())
        reader.close()
    assert got == bodies
    assert sorted(os.listdir(tmp_path)) == sorted(os.path.basename(p) for p in sink.stats.files)


def test_max_splits_keeps_only_the_newest_files(tmp_path: Path) -> None:
    sink = RecordSink(
        lambda i: open_writer(str(tmp_path / f"r_{i}.bag"), "bag"),
        buffer_bytes=0,
        split=SplitPolicy(max_bytes=2_000),
        splitting=True,
        max_splits=2,
    )
    for i in range(40):
        sink.put("/chatter", header(STRING), i, bytes(500))
    sink.close()
    assert sorted(os.listdir(tmp_path)) == [os.path.basename(p) for p in sink.stats.files]
    assert len(sink.stats.files) == 2
    assert sink.stats.files[-1].endswith("r_9.bag")


def test_an_unsplit_recording_stops_at_its_size_limit(tmp_path: Path) -> None:
    full = threading.Event()
    sink = RecordSink(
        lambda i: open_writer(str(tmp_path / "one.bag"), "bag"),
        buffer_bytes=0,
        split=SplitPolicy(max_bytes=10_000),
        on_full=full.set,
    )
    for i in range(100):
        sink.put("/chatter", header(STRING), i, bytes(1000))
    assert full.wait(5)
    sink.close()
    assert sink.held_bytes == 0
    assert 9 <= sink.stats.written <= 11
    assert sink.stats.dropped == 0  # messages after the end are not drops
    reader = open_bag(str(tmp_path / "one.bag"))
    assert reader.summary().messages == sink.stats.written
    reader.close()


def test_a_publisher_header_with_an_impossible_type_costs_only_its_own_messages(tmp_path: Path) -> None:
    sink = RecordSink(lambda i: open_writer(str(tmp_path / "t.bag"), "bag"), buffer_bytes=0)
    bad = ConnectionHeader(callerid="/evil", type="no_package", md5sum="0" * 32, message_definition="")
    sink.put("/bad", bad, 1, b"x")
    sink.put("/chatter", header(STRING), 2, string_body("ok"))
    sink.put("/bad", bad, 3, b"y")
    sink.close()
    assert (sink.stats.written, sink.stats.dropped) == (1, 2)
    reader = open_bag(str(tmp_path / "t.bag"))
    assert [c.topic for c in reader.connections] == ["/chatter"]
    reader.close()


def test_a_file_that_cannot_be_created_fails_at_once(tmp_path: Path) -> None:
    def opener(i: int) -> BagFileWriter:
        return open_writer(str(tmp_path / "no" / "such" / "dir.bag"), "bag")

    with pytest.raises(BagError, match="cannot create"):
        RecordSink(opener, buffer_bytes=0)


def test_mcap_files_decode_with_mcap_ros1_support(tmp_path: Path) -> None:
    """The reference ROS 1 decoder for MCAP (mcap-ros1-support) reads what we write."""
    from mcap.reader import make_reader
    from mcap_ros1.decoder import DecoderFactory

    path = tmp_path / "x.mcap"
    writer = open_writer(str(path), "mcap", "lz4")
    handle = writer.add_connection(STRING)
    for i in range(3):
        writer.write(handle, i, string_body(f"hello {i}"))
    writer.close()
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = [(channel.topic, msg.data) for _s, channel, _m, msg in reader.iter_decoded_messages()]
    assert decoded == [("/chatter", f"hello {i}") for i in range(3)]
