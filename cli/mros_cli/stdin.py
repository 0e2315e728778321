"""Messages read from stdin as ``rostopic pub`` reads them: one ``---``-terminated YAML document per message.

A daemon thread reads lines into a bounded queue (it waits, dropping nothing, while the publisher catches
up) and never holds up the exit; the documents are parsed and checked on the event loop as they arrive.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import os
import sys
from collections.abc import AsyncIterator
from typing import Any

import click

from mros_cli.values import build_message, load_document

__all__ = ["stdin_is_input", "stdin_messages"]


def stdin_is_input() -> bool:
    """Whether stdin is piped or redirected from a file (a terminal or /dev/null is not message input)."""
    import stat

    try:
        mode = os.fstat(sys.stdin.fileno()).st_mode
    except (OSError, ValueError, AttributeError):
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISREG(mode)


#: Lines read ahead from stdin; the reader thread waits (nothing is dropped) while the publisher catches up.
STDIN_QUEUE = 256


def start_stdin_reader(loop: asyncio.AbstractEventLoop, queue: asyncio.Queue[str]) -> None:
    """Feed stdin's lines into ``queue`` from a daemon thread ('' at EOF); it never holds up the exit."""
    import threading

    def read() -> None:
        while True:
            line = sys.stdin.readline()
            try:
                asyncio.run_coroutine_threadsafe(queue.put(line), loop).result()
            except (RuntimeError, concurrent.futures.CancelledError):
                return  # the loop is closed or closing: the command is over
            if not line:
                return

    threading.Thread(target=read, name="mros-stdin", daemon=True).start()


async def stdin_messages(cls: Any) -> AsyncIterator[Any]:
    """Messages from stdin, one per ``---``-terminated YAML document, as they arrive."""
    queue: asyncio.Queue[str] = asyncio.Queue(maxsize=STDIN_QUEUE)
    start_stdin_reader(asyncio.get_running_loop(), queue)
    buf: list[str] = []
    number = 0
    while True:
        line = await queue.get()
        if not line:
            break
        if line.strip() != "---":
            buf.append(line)
            continue
        number += 1
        value = load_document("".join(buf), f"stdin document {number}")
        buf = []
        if value is not None:
            msg = build_message(cls, value)
            msg.serialize()
            yield msg
    if "".join(buf).strip():
        click.echo("WARNING: the last document on stdin has no '---' after it; it was not published", err=True)
