"""Bag files on disk: rosbag v2 through ``rosbags``, MCAP through ``mcap``; no codec of our own.

Writers take connections (``ConnectionInfo``) and already serialized message bodies, and store the bytes as
given. A rosbag v2 file is written as ``NAME.bag.active`` and renamed to ``NAME.bag`` when closed, as rosbag
record does, so a file under its final name is always complete and indexed. Readers give connections,
messages in time order (connection, timestamp in ns, bytes) and the summary ``rosbag info`` shows. Errors of
the libraries become ``BagError`` naming the file.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Protocol

from mrosd.bag.info import BagSummary, ChunkSummary, TopicSummary
from mrosd.bag.model import BagError, ConnectionInfo

#: Formats and their file extensions.
EXTENSIONS = {"bag": ".bag", "mcap": ".mcap"}
#: Chunk compressions a writer accepts (rosbag record's -j/--bz2 and --lz4; MCAP has lz4 and zstd, no bz2).
COMPRESSIONS = ("none", "bz2", "lz4", "zstd")
_ROSBAG_MAGIC = b"#ROSBAG V"
_MCAP_MAGIC = b"\x89MCAP"
#: Overhead of one message record in a rosbag v2 chunk (record header with conn and time, two lengths),
#: counted with the body so that ``--size`` splits near the real file size while the chunk is in memory.
RECORD_OVERHEAD = 42
#: What the libraries raise on a damaged file. They check little: a flipped byte gives AssertionError,
#: KeyError, struct.error, OverflowError or MemoryError (a huge claimed length) as well as their own errors,
#: so every one of them is turned into a BagError at this boundary.
DAMAGED = (Exception,)


class BagFileWriter(Protocol):
    """What the recorder needs from a file format."""

    path: str
    written: int

    def add_connection(self, conn: ConnectionInfo) -> Any: ...

    def write(self, handle: Any, t_ns: int, data: bytes | bytearray | memoryview) -> None: ...

    def close(self) -> None: ...


class Rosbag1FileWriter:
    """A rosbag v2 file (``rosbags.rosbag1.Writer``), written as ``PATH.active`` and renamed on close."""

    def __init__(self, path: str, compression: str = "none") -> None:
        from rosbags.rosbag1 import Writer, WriterError

        self.path = path
        self.active = path + ".active"
        self.written = 0
        if os.path.exists(path):
            raise BagError(f"{path} exists already; choose another name (-O) or remove it")
        try:
            self._writer = Writer(self.active)
            if compression == "bz2":
                self._writer.set_compression(Writer.CompressionFormat.BZ2)
            elif compression == "lz4":
                self._writer.set_compression(Writer.CompressionFormat.LZ4)
            elif compression != "none":
                raise BagError(f"rosbag files support none, bz2 or lz4 compression, not {compression}")
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"cannot create {self.active}: {exc}") from exc

    def add_connection(self, conn: ConnectionInfo) -> Any:
        from rosbags.rosbag1 import WriterError
        from rosbags.typesys.msg import normalize_msgtype

        package, _, name = conn.type.partition("/")
        if not package or not name or "/" in name:
            raise BagError(f"{conn.topic}: type {conn.type!r} is not package/Name; not recorded")
        try:
            return self._writer.add_connection(
                conn.topic,
                normalize_msgtype(conn.type),  # rosbags' spelling; written back as package/Name
                msgdef=conn.message_definition,
                md5sum=conn.md5sum,
                callerid=conn.callerid or None,
                latching=1 if conn.latching else None,
            )
        except WriterError as exc:
            raise BagError(f"{self.active}: cannot add connection {conn.topic}: {exc}") from exc

    def write(self, handle: Any, t_ns: int, data: bytes | bytearray | memoryview) -> None:
        self._writer.write(handle, t_ns, memoryview(data) if isinstance(data, bytearray) else data)
        self.written += len(data) + RECORD_OVERHEAD

    def close(self) -> None:
        self._writer.close()
        os.replace(self.active, self.path)


class McapFileWriter:
    """An MCAP file with ``ros1msg`` schemas and ``ros1`` channels (what mcap-ros1-support writes and reads)."""

    def __init__(self, path: str, compression: str = "none") -> None:
        from mcap.writer import CompressionType, Writer

        kinds = {"none": CompressionType.NONE, "lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD}
        if compression not in kinds:
            raise BagError(f"MCAP files support none, lz4 or zstd compression, not {compression}")
        self.path = path
        self.written = 0
        try:
            self._file = open(path, "xb")  # noqa: SIM115  (closed in close())
        except OSError as exc:
            raise BagError(f"cannot create {path}: {exc}") from exc
        self._writer = Writer(self._file, compression=kinds[compression])
        self._writer.start(profile="ros1", library="mrosd")
        self._schemas: dict[tuple[str, str], int] = {}
        self._sequence = 0

    def add_connection(self, conn: ConnectionInfo) -> Any:
        key = (conn.type, conn.message_definition)
        schema = self._schemas.get(key)
        if schema is None:
            schema = self._writer.register_schema(
                name=conn.type, encoding="ros1msg", data=conn.message_definition.encode()
            )
            self._schemas[key] = schema
        metadata = {"md5sum": conn.md5sum, "callerid": conn.callerid, "latching": "1" if conn.latching else "0"}
        return self._writer.register_channel(
            topic=conn.topic, message_encoding="ros1", schema_id=schema, metadata=metadata
        )

    def write(self, handle: Any, t_ns: int, data: bytes | bytearray | memoryview) -> None:
        self._sequence += 1
        self._writer.add_message(
            channel_id=handle, log_time=t_ns, data=bytes(data), publish_time=t_ns, sequence=self._sequence
        )
        self.written += len(data) + 30

    def close(self) -> None:
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()


def open_writer(path: str, fmt: str, compression: str = "none") -> BagFileWriter:
    """A writer for ``fmt`` (``bag`` or ``mcap``).

    Raises:
        BagError: unknown format or compression, or the file cannot be created.
    """
    if fmt == "bag":
        return Rosbag1FileWriter(path, compression)
    if fmt == "mcap":
        return McapFileWriter(path, compression)
    raise BagError(f"unknown bag format {fmt!r}: use bag or mcap")


# --- reading ------------------------------------------------------------------------------------------


class BagReader(Protocol):
    """What play, info and ``topic echo -b`` need from a file."""

    path: str
    connections: list[ConnectionInfo]
    start_ns: int | None
    end_ns: int | None

    def messages(self, start_ns: int | None = None) -> Iterator[tuple[ConnectionInfo, int, bytes]]: ...

    def summary(self) -> BagSummary: ...

    def close(self) -> None: ...


class Rosbag1Reader:
    """A rosbag v2 file read with ``rosbags.rosbag1.Reader`` (types in ROS 1 spelling)."""

    def __init__(self, path: str) -> None:
        from rosbags.rosbag1 import Reader
        from rosbags.typesys.msg import denormalize_msgtype

        self.path = path
        self._reader = Reader(path)
        self._conns: dict[int, ConnectionInfo] = {}
        try:
            self._reader.open()
            for c in self._reader.connections:
                ext = c.ext
                self._conns[c.id] = ConnectionInfo(
                    topic=c.topic,
                    type=denormalize_msgtype(c.msgtype),
                    md5sum=c.digest,
                    message_definition=c.msgdef.data,
                    callerid=getattr(ext, "callerid", None) or "",
                    latching=bool(getattr(ext, "latching", None)),
                )
        except DAMAGED as exc:
            self.close()
            raise BagError(f"cannot read {path}: {exc or type(exc).__name__}") from exc
        self.connections = list(self._conns.values())
        infos = self._reader.chunk_infos
        counted = [ci for ci in infos if ci.connection_counts]
        # rosbag shows the first chunk's start and the last chunk's end (rosbags adds 1 ns to the end).
        self.start_ns: int | None = counted[0].start_time if counted else None
        self.end_ns: int | None = counted[-1].end_time - 1 if counted else None

    def messages(self, start_ns: int | None = None) -> Iterator[tuple[ConnectionInfo, int, bytes]]:
        conns = self._conns
        try:
            for conn, t_ns, data in self._reader.messages(start=start_ns):
                yield conns[conn.id], t_ns, data
        except DAMAGED as exc:
            raise BagError(f"{self.path} is damaged: {exc or type(exc).__name__}") from exc

    def summary(self) -> BagSummary:
        from rosbags.rosbag1.reader import Header, RecordType

        reader = self._reader
        chunks: list[ChunkSummary] = []
        assert reader.bio is not None
        try:
            for info in reader.chunk_infos:
                reader.bio.seek(info.pos)
                header = Header.read(reader.bio, RecordType.CHUNK)
                chunks.append(
                    ChunkSummary(
                        compression=header.get_string("compression"),
                        uncompressed=header.get_uint32("size"),
                        compressed=reader.chunks[info.pos].datasize,
                    )
                )
        except DAMAGED as exc:
            raise BagError(f"{self.path} is damaged: {exc or type(exc).__name__}") from exc
        counts: dict[int, int] = {}
        for info in reader.chunk_infos:
            for cid, n in info.connection_counts.items():
                counts[cid] = counts.get(cid, 0) + n
        return _summary(
            self.path,
            "2.0",
            start_ns=self.start_ns,
            end_ns=self.end_ns,
            chunks=chunks,
            conns=self._conns,
            counts=counts,
        )

    def close(self) -> None:
        if self._reader.bio is not None:
            self._reader.close()


class McapReader:
    """An MCAP file with ROS 1 channels (``ros1`` encoding, ``ros1msg`` schemas)."""

    def __init__(self, path: str) -> None:
        from mcap.reader import make_reader

        self.path = path
        try:
            self._file = open(path, "rb")  # noqa: SIM115  (closed in close())
        except OSError as exc:
            raise BagError(f"cannot read {path}: {exc}") from exc
        try:
            self._reader = make_reader(self._file)
            summary = self._reader.get_summary()
        except DAMAGED as exc:
            self._file.close()
            raise BagError(f"cannot read {path}: {exc or type(exc).__name__}") from exc
        if summary is None:
            self._file.close()
            raise BagError(f"{path} has no summary section (an unfinished recording?)")
        self._conns: dict[int, ConnectionInfo] = {}
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            if ch.message_encoding != "ros1" or schema is None:
                continue
            self._conns[cid] = ConnectionInfo(
                topic=ch.topic,
                type=schema.name,
                md5sum=ch.metadata.get("md5sum", "*"),
                message_definition=schema.data.decode(errors="replace"),
                callerid=ch.metadata.get("callerid", ""),
                latching=ch.metadata.get("latching", "0") in ("1", "true"),
            )
        self.connections = list(self._conns.values())
        stats = summary.statistics
        self._counts = dict(stats.channel_message_counts) if stats else {}
        has = stats is not None and stats.message_count > 0
        self.start_ns: int | None = stats.message_start_time if has and stats else None
        self.end_ns: int | None = stats.message_end_time if has and stats else None
        self._chunks = [
            ChunkSummary(ci.compression or "none", ci.uncompressed_size, ci.compressed_size)
            for ci in summary.chunk_indexes
        ]

    def messages(self, start_ns: int | None = None) -> Iterator[tuple[ConnectionInfo, int, bytes]]:
        try:
            for _schema, channel, message in self._reader.iter_messages(starting_at=start_ns):
                conn = self._conns.get(channel.id)
                if conn is not None:
                    yield conn, message.log_time, message.data
        except DAMAGED as exc:
            raise BagError(f"{self.path} is damaged: {exc or type(exc).__name__}") from exc

    def summary(self) -> BagSummary:
        return _summary(
            self.path,
            "mcap",
            start_ns=self.start_ns,
            end_ns=self.end_ns,
            chunks=self._chunks,
            conns=self._conns,
            counts=self._counts,
        )

    def close(self) -> None:
        self._file.close()


def _summary(
    path: str,
    version: str,
    *,
    start_ns: int | None,
    end_ns: int | None,
    chunks: list[ChunkSummary],
    conns: dict[int, ConnectionInfo],
    counts: dict[int, int],
) -> BagSummary:
    types: dict[str, str] = {}
    topics: dict[str, list[Any]] = {}
    for cid, conn in conns.items():
        types.setdefault(conn.type, conn.md5sum)
        entry = topics.setdefault(conn.topic, [conn.type, 0, 0])
        entry[1] += counts.get(cid, 0)
        entry[2] += 1
    return BagSummary(
        path=path,
        version=version,
        size=Path(path).stat().st_size,
        start_ns=start_ns,
        end_ns=end_ns,
        messages=sum(counts.get(cid, 0) for cid in conns),
        chunks=chunks,
        types=types,
        topics=[TopicSummary(t, ty, n, c) for t, (ty, n, c) in topics.items()],
    )


def open_bag(path: str) -> BagReader:
    """Open a rosbag v2 or MCAP file, chosen by its first bytes.

    Raises:
        BagError: the file is missing, of another format, unindexed or damaged.
    """
    try:
        with open(path, "rb") as f:
            magic = f.read(9)
    except OSError as exc:
        raise BagError(f"cannot read {path}: {exc.strerror or exc}") from exc
    if magic.startswith(_ROSBAG_MAGIC):
        return Rosbag1Reader(path)
    if magic.startswith(_MCAP_MAGIC):
        return McapReader(path)
    raise BagError(f"{path} is neither a rosbag (v2) nor an MCAP file")
