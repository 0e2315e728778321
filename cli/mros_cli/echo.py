"""What ``mros topic echo`` does with each message: decode it with the publisher's definition, filter, render
(``mros_cli.output``) and queue it for the stdout writer (``mros_cli.writer``)."""

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

__all__ = ["Echo", "MessageFilter", "field_type"]

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
