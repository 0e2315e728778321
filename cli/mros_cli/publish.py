"""``mros topic pub``: publish messages built from YAML arguments, a YAML file or stdin, as ``rostopic pub``."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator
from typing import Any

import click

from mros_cli.main import anonymous, master_uri, resolve_name, run
from mros_cli.stdin import stdin_is_input, stdin_messages
from mros_cli.values import build_message_or_hint, file_documents, message_class, parse_pub_args
from mrosd.errors import MrosError

__all__ = ["ONCE_DELAY", "pub"]

#: rostopic pub -1 keeps its latched message up this long so that subscribers can connect.
ONCE_DELAY = 3.0
#: -f/stdin input without -r, -l or -1 is published at this rate, as rostopic does.
STREAM_RATE = 10.0
#: How long -f/stdin publishing waits for a first subscriber before it starts (rostopic: 5 s).
STREAM_SUBSCRIBER_WAIT = 5.0


@click.command()
@click.argument("topic")
@click.argument("msg_type", metavar="TYPE")
@click.argument("args", nargs=-1)
@click.option("-r", "--rate", type=click.FloatRange(min=0, min_open=True), help="Publish at this rate (Hz).")
@click.option("-1", "--once", is_flag=True, help="Publish one latched message, wait 3 s for subscribers, exit.")
@click.option("-l", "--latch", is_flag=True, help="Latch the message (with -r, -f or stdin; otherwise always).")
@click.option("-n", "count", type=click.IntRange(min=1), help="With -r: exit after N messages.")
@click.option(
    "-f",
    "--file",
    "path",
    metavar="FILE",
    help="Read messages from a YAML file, one document per message ('-' for stdin).",
)
def pub(  # noqa: PLR0917  (one parameter per click option)
    topic: str,
    msg_type: str,
    args: tuple[str, ...],
    rate: float | None,
    once: bool,
    latch: bool,
    count: int | None,
    path: str | None,
) -> None:
    """Publish a message built from YAML arguments, as rostopic pub does.

    Without -r the message is published once, latched, until Ctrl-C. Put ``--`` before negative numbers.

    With -f FILE (or with no values and a pipe on stdin) each YAML document is one message, published at
    10 Hz unless -r, -l or -1 says otherwise; a file holding a single message with -r is repeated at that
    rate. On stdin a document ends at a ``---`` line (what ``mros topic echo`` prints), as in rostopic; an
    unterminated last document is not published and a warning says so.

    \b
    Examples:
      mros topic pub /chatter std_msgs/String "data: hello" -r 10
      mros topic pub -1 /chatter std_msgs/String hello
      mros topic pub /cmd_vel geometry_msgs/Twist "{linear: {x: 0.5}, angular: {z: 0.1}}" -r 5
      mros topic pub -1 /n std_msgs/Int32 -- -5
      mros topic pub /cmd_vel geometry_msgs/Twist -f twists.yaml
      mros topic echo /chatter | mros topic pub /copy std_msgs/String
    """
    if once and rate is not None:
        raise click.UsageError("give only one of -r and -1")
    if path is not None and args:
        raise click.UsageError("give message values either as arguments or with -f, not both")
    name = resolve_name(topic)
    cls = message_class(msg_type)
    from_stdin = path == "-" or (path is None and not args and bool(cls.__struct_fields__) and stdin_is_input())
    if path is not None and path != "-":
        docs = [build_message_or_hint(cls, d) for d in file_documents(path)]
        for m in docs:
            m.serialize()  # every message is checked before the first one is published
        _publish_stream(name, cls, iter_list(docs), rate, once, latch, count, repeat_single=len(docs) == 1)
        return
    if from_stdin:
        _publish_stream(name, cls, None, rate, once, latch, count, repeat_single=False)
        return
    msg = build_message_or_hint(cls, parse_pub_args(args))
    msg.serialize()  # fail now, with the field named, rather than in the publisher
    latched = latch or rate is None

    async def main() -> None:
        from mrosd.tcpros import Node  # aiohttp and the TCPROS stack: only when a node is needed

        async with Node(anonymous("pub"), master_uri=master_uri(), argv=[]) as node:
            publisher = await node.advertise(name, cls, latch=latched)
            if rate is None:
                note = f" for {ONCE_DELAY:g} seconds" if once else ". Press ctrl-C to terminate"
                click.echo(f"publishing and latching message{note}")
                await publisher.publish(msg)
                if once:
                    await asyncio.sleep(ONCE_DELAY)
                else:
                    await asyncio.Event().wait()
                return
            await _repeat(publisher, msg, rate, count)

    run(main())


async def iter_list(items: list[Any]) -> AsyncIterator[Any]:
    """An async iterator over ``items`` (file input is loaded and checked up front)."""
    for item in items:
        yield item


async def _repeat(publisher: Any, msg: Any, rate: float, count: int | None) -> None:
    period = 1.0 / rate
    sent = 0
    next_at = time.monotonic()
    while count is None or sent < count:
        await publisher.publish(msg)
        sent += 1
        next_at += period
        await asyncio.sleep(max(0.0, next_at - time.monotonic()))


def _publish_stream(  # noqa: PLR0917
    name: str,
    cls: Any,
    messages: Any,
    rate: float | None,
    once: bool,
    latch: bool,
    count: int | None,
    *,
    repeat_single: bool,
) -> None:
    """rostopic's -f/stdin publishing: one message per document, paced by the rate, then exit."""
    if rate is None and not latch and not once:
        rate = STREAM_RATE
    latched = latch or rate is None

    async def main() -> None:
        source = messages if messages is not None else stdin_messages(cls)
        from mrosd.tcpros import Node  # aiohttp and the TCPROS stack: only when a node is needed

        async with Node(anonymous("pub"), master_uri=master_uri(), argv=[]) as node:
            publisher = await node.advertise(name, cls, latch=latched)
            with contextlib.suppress(TimeoutError, MrosError):
                await publisher.wait_for_subscribers(1, timeout=STREAM_SUBSCRIBER_WAIT)
            if repeat_single and rate is not None and not once:
                click.echo("Got one message and a rate, publishing repeatedly")
                async for msg in source:
                    await _repeat(publisher, msg, rate, count)
                return
            sent = 0
            next_at = time.monotonic()
            async for msg in source:
                await publisher.publish(msg)
                sent += 1
                if once or (count is not None and sent >= count):
                    break
                if rate is not None:
                    next_at += 1.0 / rate
                    await asyncio.sleep(max(0.0, next_at - time.monotonic()))
            if once or (latched and sent):
                # Latched: give subscribers the same grace rostopic -1 gives them before the node goes.
                await asyncio.sleep(ONCE_DELAY)

    run(main())


# --- hz / bw ------------------------------------------------------------------------------------------
