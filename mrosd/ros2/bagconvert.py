"""``mros bag convert``: rosbag v2 -> rosbag2 (MCAP or sqlite3) with ROS 2 types, and rosbag2 -> rosbag v2.

Both directions go through the bridge's own ``TypeMapper``, so a bag crosses exactly as a live topic does:
standard types by name, custom types derived from the bag's ``message_definition`` (ROS 1 -> ROS 2) or written
in ROS 1's syntax from the bag's ROS 2 definitions with genmsg's md5 (ROS 2 -> ROS 1), mapping rules applied,
bodies converted at the byte level. ROS 1 bags are read by ``mrosd.bag`` (whose reader turns every damage into
one ``BagError``), rosbag2 bags are read and written by rosbags.

What a round trip ROS 1 -> ROS 2 -> ROS 1 keeps: every body byte for byte, except ``Header.seq`` (ROS 2 has
none: a top-level header gets a per-topic counter from 0 on the way back), plus the receive times, topics,
types (``tf/tfMessage`` comes back as ``tf2_msgs/TFMessage``), md5s and latching. What it loses: callerids
and the connection headers' other fields; a ``char`` or ``byte`` field of a custom type comes back as
``uint8``/``int8`` (same bytes, another md5).

A type that cannot cross is one line naming the topic, its messages are skipped and the others convert. An
output that fails half-way is removed, so a file under the output name is always complete.
"""

from __future__ import annotations

import os
import shutil
import struct
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import msgspec

from mrosd.bag.model import BagError, ConnectionInfo
from mrosd.errors import MrosError
from mrosd.ros2.types import TypeMapper, UnmappableTypeError

if TYPE_CHECKING:
    from mrosd.ros2.mapping import MappingRules

__all__ = ["ConvertReport", "convert_bag"]

#: progress is reported at most every this many messages (and at the end)
PROGRESS_EVERY = 500
_SEQ = struct.Struct("<I")

Progress = Callable[[int, int], None]


class ConvertReport(msgspec.Struct, kw_only=True):
    """What a conversion did: messages written and skipped, and a line per topic that did not cross."""

    output: str
    written: int = 0
    skipped: int = 0
    problems: list[str] = msgspec.field(default_factory=list)


def convert_bag(
    src: str,
    dst: str,
    *,
    to: Literal["ros1", "ros2"],
    storage: Literal["mcap", "sqlite3"] = "mcap",
    progress: Progress | None = None,
    rules: MappingRules | None = None,
    ros2_share: tuple[str, ...] = (),
) -> ConvertReport:
    """Convert ``src`` into a new ``dst`` (``to="ros2"``: a rosbag2 directory; ``to="ros1"``: a ``.bag`` file).

    Raises:
        BagError: ``src`` is missing, damaged or of the wrong kind, or ``dst`` exists or cannot be written.
    """
    if os.path.lexists(dst):
        raise BagError(f"{dst} exists already; choose another output or remove it")
    mapper = TypeMapper(rules, ros2_share)
    try:
        if to == "ros2":
            return _to_ros2(src, dst, storage, mapper, progress)
        return _to_ros1(src, dst, mapper, progress)
    except BaseException:
        _remove(dst)
        raise


def _remove(path: str) -> None:
    for p in (path, path + ".active"):
        if os.path.isdir(p) and not os.path.islink(p):
            shutil.rmtree(p, ignore_errors=True)
        elif os.path.lexists(p):
            os.unlink(p)


def _to_ros2(src: str, dst: str, storage: str, mapper: TypeMapper, progress: Progress | None) -> ConvertReport:
    from rosbags.convert.converter import LATCH
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

    from mrosd.bag.files import Rosbag1Reader, open_bag

    reader = open_bag(src)
    report = ConvertReport(output=dst)
    try:
        if not isinstance(reader, Rosbag1Reader) and not src.endswith(".mcap"):
            raise BagError(f"{src}: --to ros2 reads a ROS 1 bag")
        total = reader.summary().messages
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(Path(dst), version=9, storage_plugin=plugin)
        conns: dict[ConnectionInfo, Any] = {}
        skip: set[ConnectionInfo] = set()
        try:
            writer.open()
            done = 0
            for info, t_ns, data in reader.messages():
                done += 1
                if info in skip:
                    report.skipped += 1
                    continue
                entry = conns.get(info)
                if entry is None:
                    try:
                        mapping = mapper.mapping(info.type, info.message_definition)
                    except UnmappableTypeError as exc:
                        report.problems.append(f"{info.topic}: {exc}; its messages are skipped")
                        skip.add(info)
                        report.skipped += 1
                        continue
                    entry = conns[info] = (
                        _ros2_connection(writer, info, mapping.ros2_type, mapper, LATCH),
                        mapping.ros2_type,
                    )
                try:
                    cdr = mapper.to_cdr(entry[1], data)
                except MrosError as exc:
                    report.problems.append(f"{info.topic} at {t_ns} ns: {exc}; skipped")
                    report.skipped += 1
                    continue
                writer.write(entry[0], t_ns, cdr)
                report.written += 1
                if progress is not None and done % PROGRESS_EVERY == 0:
                    progress(done, total)
        except WriterError as exc:
            raise BagError(f"cannot write {dst}: {exc}") from exc
        finally:
            try:
                writer.close()
            except WriterError as exc:
                raise BagError(f"cannot finish {dst}: {exc}") from exc
        if progress is not None:
            progress(total, total)
    finally:
        reader.close()
    return report


def _ros2_connection(writer: Any, info: ConnectionInfo, ros2_type: str, mapper: TypeMapper, latch: Any) -> Any:
    """A rosbag2 connection per (topic, type, latching); the same topic twice (two publishers) shares it."""
    for conn in writer.connections:
        if conn.topic == info.topic and conn.msgtype == ros2_type:
            return conn
    return writer.add_connection(
        info.topic, ros2_type, typestore=mapper.store, offered_qos_profiles=latch if info.latching else []
    )


def _to_ros1(src: str, dst: str, mapper: TypeMapper, progress: Progress | None) -> ConvertReport:
    from rosbags.rosbag2 import Reader

    from mrosd.bag.files import Rosbag1FileWriter

    if not dst.endswith(".bag"):
        raise BagError(f"{dst}: --to ros1 writes a .bag file")
    reader = Reader(Path(src))
    try:
        reader.open()
    except Exception as exc:  # rosbags' errors on a missing, foreign or damaged bag
        raise BagError(f"cannot read {src} as a rosbag2: {exc or type(exc).__name__}") from exc
    report = ConvertReport(output=dst)
    writer = Rosbag1FileWriter(dst)
    try:
        total = reader.message_count
        targets: dict[int, tuple[Any, str, bool] | None] = {}
        seqs: dict[str, int] = {}
        done = 0
        for rconn, t_ns, data in reader.messages():
            done += 1
            target = targets.get(rconn.id, ...)
            if target is ...:
                target = targets[rconn.id] = _ros1_connection(writer, rconn, mapper, report)
            if target is None:
                report.skipped += 1
                continue
            handle, ros2_type, has_header = target
            try:
                body = mapper.to_ros1(ros2_type, data)
            except MrosError as exc:
                report.problems.append(f"{rconn.topic} at {t_ns} ns: {exc}; skipped")
                report.skipped += 1
                continue
            if has_header:
                out = bytearray(body)
                seq = seqs.get(rconn.topic, 0)
                seqs[rconn.topic] = seq + 1
                _SEQ.pack_into(out, 0, seq & 0xFFFFFFFF)
                body = memoryview(out)
            writer.write(handle, t_ns, body)
            report.written += 1
            if progress is not None and done % PROGRESS_EVERY == 0:
                progress(done, total)
        writer.close()
        if progress is not None:
            progress(total, total)
    except BagError:
        raise
    except MrosError:
        raise
    except Exception as exc:  # rosbags' reader on damaged storage
        raise BagError(f"{src} is damaged: {exc or type(exc).__name__}") from exc
    finally:
        reader.close()
    return report


def _ros1_connection(
    writer: Any, rconn: Any, mapper: TypeMapper, report: ConvertReport
) -> tuple[Any, str, bool] | None:
    """The ROS 1 connection of a rosbag2 connection, registering the bag's own ROS 2 definitions first; None
    (and a problem line) when the type cannot cross."""
    ros2_type = rconn.msgtype
    try:
        if ros2_type not in mapper.store.types:
            _register_bag_types(mapper, rconn)
        back = mapper.ros1_for(ros2_type)
    except MrosError as exc:
        report.problems.append(f"{rconn.topic}: {exc}; its messages are skipped")
        return None
    qos = getattr(rconn.ext, "offered_qos_profiles", None) or []
    latching = any(getattr(q.durability, "value", 0) == 1 for q in qos)
    info = ConnectionInfo(rconn.topic, back.ros1_type, back.md5sum, back.definition, latching=latching)
    fields = mapper.store.fielddefs[ros2_type][1]
    has_header = bool(fields) and fields[0][1][0].name == "NAME" and fields[0][1][1] == "std_msgs/msg/Header"
    return writer.add_connection(info), ros2_type, has_header


def _register_bag_types(mapper: TypeMapper, rconn: Any) -> None:
    """The ROS 2 definitions a rosbag2 stores with a connection, added to the mapper's store where missing."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    msgdef = rconn.msgdef
    if msgdef is None or not msgdef.data:
        raise UnmappableTypeError(f"ros2: {rconn.msgtype}: the bag holds no definition of it")
    try:
        if msgdef.format == MessageDefinitionFormat.IDL:
            parsed = get_types_from_idl(msgdef.data)
        else:
            parsed = _types_from_concatenated_msg(msgdef.data, rconn.msgtype, get_types_from_msg)
    except Exception as exc:  # rosbags' parser errors
        raise UnmappableTypeError(f"ros2: {rconn.msgtype}: the bag's definition does not parse: {exc}") from exc
    fresh = {name: fdef for name, fdef in parsed.items() if name not in mapper.store.types}
    try:
        mapper.store.register(fresh)
    except Exception as exc:
        raise UnmappableTypeError(f"ros2: {rconn.msgtype}: rosbags refused the bag's definition: {exc}") from exc


def _types_from_concatenated_msg(text: str, name: str, parse: Callable[[str, str], Any]) -> dict[str, Any]:
    """A ``ros2msg`` schema: the type's text, then ``=====`` lines each followed by ``MSG: pkg/msg/Type`` and its
    text (rosbag2's layout, as ROS 1's message_definition)."""
    types: dict[str, Any] = {}
    sections = text.split("\n" + "=" * 80 + "\n")
    types.update(parse(sections[0], name))
    for section in sections[1:]:
        head, _, body = section.partition("\n")
        if not head.startswith("MSG: "):
            continue
        sub = head[5:].strip()
        if sub.count("/") == 1:
            pkg, _, typ = sub.partition("/")
            sub = f"{pkg}/msg/{typ}"
        types.update(parse(body, sub))
    return types
