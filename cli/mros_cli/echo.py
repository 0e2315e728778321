"""What ``mros topic echo`` does with each message: decode it with the publisher's definition, filter, render
(``mros_cli.output``) and queue it for the stdout writer (``mros_cli.writer``).

Also where a name typed as ``/topic/field/sub`` is split into its topic and field path (``split_topic``),
and the bag-reading half of ``mros topic echo -b BAG`` (``echo_bag``): the messages come from a file
instead of a connection, and the same ``Echo`` renders them.
"""

from __future__ import annotations

import asyncio
import sys
import time
from typing import Any

import click

from mros_cli.output import SEPARATOR, Decoder, JsonRenderer, PlotRenderer, TextRenderer, extract_field
from mros_cli.writer import CoalescedWriter
from mrosd.errors import MrosError
from mrosd.msg import get_message_class

__all__ = ["Echo", "MessageFilter", "StoredMessage", "echo_bag", "field_type", "split_topic"]

_SEPARATOR_BYTES = SEPARATOR.encode()


def field_type(msg_type: str, fields: list[str]) -> str:
    """The type of ``msg_type``'s field at the path ``fields`` (as ``rostopic type TOPIC/field`` prints it)."""
    current = msg_type
    for name in fields:
        cls = get_message_class("std_msgs/Header" if current == "Header" else current)
        table = dict(zip(cls.__struct_fields__, cls._field_types, strict=True))
        if name not in table:
            raise MrosError(f"{current} has no field {name!r}; its fields are: {', '.join(table)}")
        current = table[name]
    return current


class MessageFilter:
    """``--filter EXPR``: a Python expression evaluated per message with ``m`` (the message) and ``topic``.

    This runs code given on the command line, in this process, exactly as rostopic's ``--filter`` does; it is
    the user's own expression, never data from the graph. A message for which the expression raises is not
    shown, and the first such error is reported on stderr in one line (rostopic prints a traceback per message).
    """

    def __init__(self, expression: str, topic: str) -> None:
        try:
            self.code = compile(expression, "<--filter>", "eval")
        except SyntaxError as exc:
            raise MrosError(f"--filter {expression!r} is not a Python expression: {exc.msg}") from exc
        self.expression = expression
        self.topic = topic
        self.warned = False

    def __call__(self, msg: Any) -> bool:
        try:
            return bool(eval(self.code, {"m": msg, "topic": self.topic}))  # the user's own expression, as rostopic
        except Exception as exc:  # any error of the user's expression skips the message
            if not self.warned:
                self.warned = True
                click.echo(f"WARNING: --filter {self.expression!r} raised {type(exc).__name__}: {exc}", err=True)
            return False


class Echo:
    """Decodes raw messages with the publisher's own definition and writes them, coalesced per loop turn."""

    def __init__(
        self,
        fields: list[str],
        count: int | None,
        *,
        noarr: bool,
        as_json: bool,
        offset: bool,
        nostr: bool = False,
        plot: bool = False,
        keep: MessageFilter | None = None,
    ) -> None:
        self.fields = fields
        self.count = count
        self.shown = 0
        self.offset = offset
        self.keep = keep
        self.text = TextRenderer(noarr=noarr, nostr=nostr)
        self.json = JsonRenderer() if as_json else None
        self.plot = PlotRenderer(noarr=noarr, nostr=nostr) if plot else None
        self.done = asyncio.Event()
        self.error: BaseException | None = None
        self.decoder = Decoder()
        # A writer thread: rendering the next image overlaps waiting for the reader to take the last one.
        self.writer = CoalescedWriter(sys.stdout.buffer, on_broken=self._output_gone, background=True)
        self._field_type: str | None = None

    def on_raw(self, raw: Any) -> None:
        """Subscriber callback: decode, filter, render, queue for the coalesced write."""
        if self.done.is_set():
            return
        try:
            msg = self.decoder.decode(raw)
            if self.keep is not None and not self.keep(msg):
                return
            value = extract_field(msg, self.fields) if self.fields else msg
            self.writer.add(self._render(value, type(msg), getattr(raw, "stamp_ns", None)))
        except (MrosError, KeyError) as exc:
            self.error = exc
            self.done.set()
            return
        self.shown += 1
        if self.count is not None and self.shown >= self.count:
            self.writer.flush()
            self.done.set()

    def _render(self, value: Any, cls: Any, recorded_ns: int | None) -> list[bytes | bytearray]:
        if self.json is not None:
            return [self.json.render(value) + b"\n"]
        now = time.time_ns()
        if self.plot is not None:
            row = self.plot.row(value, now, now if self.offset else None, recorded_ns=recorded_ns) + "\n"
            return [(self.plot.heading(value) + "\n" + row).encode() if self.shown == 0 else row.encode()]
        if self.offset:
            self.text.offset_ns = now
        type_info = self._type_info(cls) if self.fields else None
        return [*self.text.render_chunks(value, type_info), _SEPARATOR_BYTES]

    def _type_info(self, cls: Any) -> str | None:
        if self._field_type is None:
            try:
                self._field_type = field_type(cls._type, [f.split("[", 1)[0] for f in self.fields])
            except MrosError:
                self._field_type = ""
        return self._field_type or None

    def _output_gone(self) -> None:
        """The reader closed stdout (``| head``: done, quietly), or a write failed (an error to report)."""
        if self.writer.error is not None and self.error is None:
            self.error = MrosError(f"cannot write to stdout: {self.writer.error}")
        self.done.set()

    def flush(self) -> None:
        """Write what is still queued, and wait until it is written."""
        self.writer.close()


def split_topic(name: str, types: dict[str, str]) -> tuple[str, str, list[str]] | None:
    """``/topic/field/sub`` -> (topic, type, [field, sub]) by exact, else longest-prefix, match.

    As rostopic, a prefix whose type is known locally and has no such field is not a match (so echo keeps
    waiting for the topic); one whose type is not known locally is taken as it is.
    """
    if name in types:
        return name, types[name], []
    candidates = sorted((t for t in types if name.startswith(t.rstrip("/") + "/")), key=len, reverse=True)
    for topic in candidates:
        fields = [f for f in name[len(topic) :].split("/") if f]
        if _has_fields(types[topic], name[len(topic) :].split("[", 1)[0]):
            return topic, types[topic], fields
    return None


def _has_fields(msg_type: str, path: str) -> bool:
    """False only when ``msg_type`` is known locally and has no field ``path`` (``a/b``; True if unknown)."""
    names = [f for f in path.split("/") if f]
    if not names:
        return True
    try:
        get_message_class(msg_type)
    except MrosError:
        return True
    try:
        field_type(msg_type, names)
    except MrosError:
        return False
    return True


class StoredMessage:
    """A stored message in the shape ``mros topic echo`` renders (like ``RawMessage``: data and header),
    with the time it was recorded (``stamp_ns``, what ``rostopic echo -b -p`` prints as ``%time``)."""

    __slots__ = ("data", "header", "stamp_ns")

    def __init__(self, data: bytes, header: dict[str, str], stamp_ns: int) -> None:
        self.data = data
        self.header = header
        self.stamp_ns = stamp_ns


def echo_bag(path: str, name: str, echo_factory: Any) -> None:
    """``mros topic echo -b BAG NAME``: render the stored messages of a topic (or one field of it).

    ``echo_factory(fields)`` builds the renderer (an ``Echo``) for the field path that follows
    the topic in ``name``; it is called inside the running loop and fed ``StoredMessage`` objects in time
    order until its ``done`` event is set (``-n``) or the topic's messages end.

    Raises:
        BagError: the bag cannot be read, or holds no topic matching ``name``.
    """
    from mros_cli.main import run
    from mrosd.bag.files import open_bag
    from mrosd.bag.model import BagError

    async def main() -> None:
        reader = open_bag(path)
        try:
            types = {c.topic: c.type for c in reader.connections}
            found = split_topic(name, types)
            if found is None:
                raise BagError(f"{path} has no topic {name}; it has: {', '.join(sorted(types)) or 'none'}")
            topic, _type, fields = found
            echo = echo_factory(fields)
            headers: dict[Any, dict[str, str]] = {}
            for count, (conn, t_ns, data) in enumerate(reader.messages()):
                if conn.topic != topic:
                    continue
                header = headers.get(conn)
                if header is None:
                    header = headers[conn] = {
                        "type": conn.type,
                        "md5sum": conn.md5sum,
                        "message_definition": conn.message_definition,
                    }
                echo.on_raw(StoredMessage(data, header, t_ns))
                if echo.done.is_set():
                    break
                if count % 256 == 255:
                    await asyncio.sleep(0)  # let the coalesced writes go out
            echo.flush()
            if echo.error is not None:
                raise BagError(f"cannot show {name}: {echo.error}")
        finally:
            reader.close()

    run(main())
