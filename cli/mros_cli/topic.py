"""``mros topic``: list, inspect, find, echo, publish and measure topics, with rostopic's output.

``list`` (and ``list --watch``, through ``mros_cli.graph``), ``info``, ``type`` and ``find`` only ask the
master. ``echo``, ``hz``, ``bw`` and ``delay`` subscribe in raw mode (``AnyMsg``) so they need no local
definition of the type: messages are decoded with a class built from the publisher's ``message_definition``
(``mrosd.msg.load_type``), the way a ROS user wishes rostopic did. ``pub`` lives in ``mros_cli.publish``; the
YAML-to-message builder in ``mros_cli.values``; what echo does with each message in ``mros_cli.echo``,
rendering in ``mros_cli.output``, the stdout writer in ``mros_cli.writer``; the statistics in ``mros_cli.stats``.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
import time
from typing import TYPE_CHECKING, Any

import click

from mros_cli.echo import Echo, MessageFilter, echo_bag, field_type, split_topic
from mros_cli.graph import poll_option, shared_memory_section, watch_topics
from mros_cli.main import anonymous, master_client, resolve_name, run
from mros_cli.output import Decoder
from mros_cli.publish import pub
from mros_cli.stats import BandwidthStats, DelayStats, RateStats
from mros_cli.values import build_message, file_documents, parse_pub_args
from mrosd.errors import MrosError

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient

#: Re-exported for ``mros_cli.ixm`` and older imports; the builder lives in ``mros_cli.values``.
__all__ = ["build_message", "file_documents", "group", "parse_pub_args"]

#: rostopic hz's default window ("-1": effectively everything).
HZ_WINDOW = 50000
#: rostopic bw's default window.
BW_WINDOW = 100
#: rostopic delay's default window ("-1": effectively everything).
DELAY_WINDOW = 50000
#: How often echo/hz/bw/delay look for a topic that is not published yet.
TOPIC_POLL = 0.5


async def topic_types(master: MasterClient) -> dict[str, str]:
    """Topic -> type for every topic the master knows (published or subscribed)."""
    pairs = await master.get_topic_types()
    return {str(t): str(ty) for t, ty in pairs}


async def wait_for_topic(master: MasterClient, name: str) -> tuple[str, str, list[str]]:
    """Block until ``name`` (or its topic prefix) is known to the master, warning once like rostopic."""
    warned = False
    while True:
        found = split_topic(name, await topic_types(master))
        if found is not None and found[1] != "*":
            return found
        if not warned:
            click.echo(f"WARNING: topic [{name}] does not appear to be published yet", err=True)
            warned = True
        await asyncio.sleep(TOPIC_POLL)


@click.group(name="topic")
def group() -> None:
    """List, inspect, echo, publish and measure topics (like rostopic).

    \b
    Examples:
      mros topic list -v
      mros topic echo /chatter -n 1
      mros topic echo /odom/pose/pose/position --noarr
      mros topic echo /chatter --json | jq .data
      mros topic pub /chatter std_msgs/String "data: hello" -r 10
      mros topic pub -1 /cmd_vel geometry_msgs/Twist "{linear: {x: 0.5}}"
      mros topic hz /camera/image
      mros topic find sensor_msgs/Image
    """


# --- master-only commands -----------------------------------------------------------------------------


@group.command(name="list")
@click.option("-v", "--verbose", is_flag=True, help="Print types and publisher/subscriber counts.")
@click.option("-p", "publishers_only", is_flag=True, help="Only published topics.")
@click.option("-s", "subscribers_only", is_flag=True, help="Only subscribed topics.")
@click.option(
    "--watch",
    is_flag=True,
    help="Print topics as they appear (+) and vanish (-), starting with the current ones, until Ctrl-C.",
)
@click.option("--json", "as_json", is_flag=True, help="With --watch: one JSON object per line (as mros graph watch).")
@poll_option
@click.argument("namespace", required=False)
def list_(  # noqa: PLR0917  (one parameter per click option)
    verbose: bool,
    publishers_only: bool,
    subscribers_only: bool,
    watch: bool,
    as_json: bool,
    poll: float,
    namespace: str | None,
) -> None:
    """List the topics the master knows, sorted (``-v`` as ``rostopic list -v``).

    With ``--watch``, the topic lines of ``mros graph watch``: pushed by an mrosd master, polled from
    rosmaster every ``--poll`` seconds.

    \b
    Examples:
      mros topic list
      mros topic list -v
      mros topic list --watch /camera
    """
    if publishers_only and subscribers_only:
        raise click.UsageError("give only one of -p and -s")
    if watch:
        if verbose or publishers_only or subscribers_only:
            raise click.UsageError("--watch lists every topic: it takes no -v, -p or -s")
        watch_topics(resolve_name(namespace) if namespace else None, as_json=as_json, poll=poll)
        return
    if as_json:
        raise click.UsageError("--json applies to --watch")

    async def main() -> tuple[tuple[Any, ...], dict[str, str]]:
        async with master_client() as master:
            state = await master.get_system_state()
            return state, await topic_types(master)

    state, types = run(main())
    pubs = [(t, types.get(t, "unknown type"), n) for t, n in state[0]]
    subs = [(t, types.get(t, "unknown type"), n) for t, n in state[1]]
    if namespace:
        ns = resolve_name(namespace)
        prefix = ns.rstrip("/") + "/"
        pubs = [p for p in pubs if p[0] == ns or p[0].startswith(prefix)]
        subs = [s for s in subs if s[0] == ns or s[0].startswith(prefix)]
    lines: list[str] = []
    if verbose:
        if not subscribers_only:
            lines.append("\nPublished topics:")
            for t, ty, nodes in pubs:
                many = len(nodes) > 1
                lines.append(f" * {t} [{ty}] {len(nodes)} publishers" if many else f" * {t} [{ty}] 1 publisher")
        if not publishers_only:
            lines.append("")
            lines.append("Subscribed topics:")
            for t, ty, nodes in subs:
                lines.append(
                    f" * {t} [{ty}] {len(nodes)} subscribers" if len(nodes) > 1 else f" * {t} [{ty}] 1 subscriber"
                )
        lines.append("")
    else:
        if publishers_only:
            topics = {t for t, _, _ in pubs}
        elif subscribers_only:
            topics = {t for t, _, _ in subs}
        else:
            topics = {t for t, _, _ in pubs} | {t for t, _, _ in subs}
        lines.append("\n".join(sorted(topics)))
    click.echo("\n".join(lines))


@group.command()
@click.argument("topic")
def info(topic: str) -> None:
    """Print a topic's type, publishers, subscribers and the connections that use shared memory.

    \b
    Example:
      mros topic info /chatter
    """
    name = resolve_name(topic)

    async def main() -> str:
        async with master_client() as master:
            state = await master.get_system_state()
            types = await topic_types(master)
            pubs = [n for t, nodes in state[0] if t == name for n in nodes]
            subs = [n for t, nodes in state[1] if t == name for n in nodes]
            if not pubs and not subs:
                raise MrosError(f"Unknown topic {name}")

            async def api(node: str) -> str:
                try:
                    uri: str = await master.lookup_node(node)
                except MrosError:
                    return "unknown"
                return uri

            text = f"Type: {types.get(name, 'unknown type')}\n\n"
            text += "Publishers: \n" if pubs else "Publishers: None\n"
            for n in pubs:
                text += f" * {n} ({await api(n)})\n"
            text += "\n"
            text += "Subscribers: \n" if subs else "Subscribers: None\n"
            for n in subs:
                text += f" * {n} ({await api(n)})\n"
            return text + "\n" + await shared_memory_section(master, name, pubs)

    click.echo(run(main()))


@group.command(name="type")
@click.argument("topic")
def type_(topic: str) -> None:
    """Print a topic's message type (``/topic/field`` adds the field and its type).

    \b
    Examples:
      mros topic type /chatter
      mros topic type /odom/pose/pose
    """
    name = resolve_name(topic)

    async def main() -> tuple[str, str, list[str]] | None:
        async with master_client() as master:
            return split_topic(name, await topic_types(master))

    found = run(main())
    if found is None:
        click.echo(f"unknown topic type [{name}]", err=True)
        sys.exit(1)
    _real, msg_type, fields = found
    if not fields:
        click.echo(msg_type)
        return
    click.echo(f"{msg_type} {'/'.join(fields)} {field_type(msg_type, fields)}")


@group.command()
@click.argument("msg_type", metavar="TYPE")
def find(msg_type: str) -> None:
    """Print the topics of a message type, in the master's order (as rostopic find).

    \b
    Example:
      mros topic find sensor_msgs/Image
    """

    async def main() -> list[str]:
        async with master_client() as master:
            return [t for t, ty in (await topic_types(master)).items() if ty == msg_type]

    click.echo("\n".join(run(main())))


# --- echo ---------------------------------------------------------------------------------------------


filter_option = click.option(
    "--filter",
    "filter_expr",
    metavar="EXPR",
    help="Only messages for which this Python expression is true; it sees m (the message) and topic. "
    "It runs as local code, as rostopic's --filter does.",
)


@group.command()
@click.argument("topic")
@click.option("-n", "count", type=click.IntRange(min=1), help="Exit after N messages.")
@click.option("-p", "plot", is_flag=True, help="Plot-friendly CSV, as rostopic echo -p.")
@filter_option
@click.option("--noarr", is_flag=True, help="Show arrays as <array type: T, length: N> (with -p: leave them out).")
@click.option("--nostr", is_flag=True, help="Show strings as <string length: N> (with -p: leave them out).")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per line instead of YAML text.")
@click.option("--offset", is_flag=True, help="Print time fields as offsets from the current time.")
@click.option("-b", "--bag", "bag", metavar="BAGFILE", help="Echo the messages stored in a bag file instead.")
def echo(  # noqa: PLR0917  (one parameter per click option)
    topic: str,
    count: int | None,
    plot: bool,
    filter_expr: str | None,
    noarr: bool,
    nostr: bool,
    as_json: bool,
    offset: bool,
    bag: str | None,
) -> None:
    """Print messages as rostopic echo does (``---`` after each); ``/topic/field`` prints one field.

    The type need not be known locally: it is built from the publisher's message definition. A topic (or
    the topic of a field path) that is not published yet is waited for, with a warning, as rostopic does.

    \b
    Examples:
      mros topic echo /chatter
      mros topic echo /odom/pose/pose/position -n 1
      mros topic echo /scan --noarr
      mros topic echo -p /odom/pose/pose/position > pos.csv
      mros topic echo /chatter --filter "'hello' in m.data"
      mros topic echo /chatter --json
      mros topic echo -b run.bag /chatter
    """
    if plot and as_json:
        raise click.UsageError("give only one of -p and --json")
    name = resolve_name(topic)
    if bag is not None:
        if offset:
            raise click.UsageError("--offset does not apply to bag files (as in rostopic)")
        keep_bag = MessageFilter(filter_expr, name) if filter_expr is not None else None
        echo_bag(
            bag,
            name,
            lambda fields: Echo(
                fields, count, noarr=noarr, nostr=nostr, as_json=as_json, offset=False, plot=plot, keep=keep_bag
            ),
        )
        return

    async def main() -> None:
        async with master_client() as master:
            real, _type, fields = await wait_for_topic(master, name)
        keep = MessageFilter(filter_expr, real) if filter_expr is not None else None
        echo = Echo(fields, count, noarr=noarr, nostr=nostr, as_json=as_json, offset=offset, plot=plot, keep=keep)
        from mrosd.tcpros import AnyMsg, Node  # aiohttp and the TCPROS stack: only when a node is needed

        async with Node(anonymous("echo"), master_uri=master.master_uri, argv=[]) as node:
            await node.subscribe(real, AnyMsg, callback=echo.on_raw)
            await echo.done.wait()
            echo.flush()
        if echo.error is not None:
            raise MrosError(f"cannot show {name}: {echo.error}")

    run(main())


# --- hz / bw / delay ----------------------------------------------------------------------------------


async def _measure(topic: str, on_raw: Any, tick: Any, duration: float | None) -> None:
    async with master_client() as master:
        real, _type, _fields = await wait_for_topic(master, resolve_name(topic))
    from mrosd.tcpros import AnyMsg, Node  # aiohttp and the TCPROS stack: only when a node is needed

    async with Node(anonymous("measure"), master_uri=master.master_uri, argv=[]) as node:
        await node.subscribe(real, AnyMsg, callback=on_raw)
        click.echo(f"subscribed to [{real}]")
        end = None if duration is None else time.monotonic() + duration
        while end is None or time.monotonic() < end:
            await asyncio.sleep(1.0)
            tick()


window_help = "Number of messages to average over."


@group.command()
@click.argument("topic")
@click.option("-w", "--window", type=click.IntRange(min=2), default=HZ_WINDOW, show_default=True, help=window_help)
@filter_option
@click.option("--duration", type=float, help="Stop after this many seconds.")
def hz(topic: str, window: int, filter_expr: str | None, duration: float | None) -> None:
    """Print a topic's publishing rate every second (rostopic hz's format).

    \b
    Examples:
      mros topic hz /camera/image -w 100
      mros topic hz /chatter --filter "m.data.startswith('hello')"
    """
    stats = RateStats(window)
    keep = MessageFilter(filter_expr, resolve_name(topic)) if filter_expr is not None else None
    decoder = Decoder()

    def on_raw(raw: Any) -> None:
        if keep is None or keep(decoder.decode(raw)):
            stats.on_message(time.time())

    async def main() -> None:
        await _measure(topic, on_raw, lambda: click.echo(stats.report()), duration)

    with contextlib.suppress(KeyboardInterrupt):
        run(main())


@group.command()
@click.argument("topic")
@click.option("-w", "--window", type=click.IntRange(min=2), default=BW_WINDOW, show_default=True, help=window_help)
@click.option("--duration", type=float, help="Stop after this many seconds.")
def bw(topic: str, window: int, duration: float | None) -> None:
    """Print a topic's bandwidth every second (rostopic bw's format).

    \b
    Example:
      mros topic bw /camera/image
    """
    stats = BandwidthStats(window)

    def tick() -> None:
        text = stats.report(time.time())
        if text is not None:
            click.echo(text)

    async def main() -> None:
        await _measure(topic, lambda raw: stats.on_message(time.time(), len(raw.data)), tick, duration)

    with contextlib.suppress(KeyboardInterrupt):
        run(main())


@group.command()
@click.argument("topic")
@click.option("-w", "--window", type=click.IntRange(min=2), default=DELAY_WINDOW, show_default=True, help=window_help)
@click.option("--duration", type=float, help="Stop after this many seconds.")
def delay(topic: str, window: int, duration: float | None) -> None:
    """Print the delay between a message's header stamp and its arrival, every second (rostopic delay).

    The topic's messages must start with a Header.

    \b
    Example:
      mros topic delay /camera/image
    """
    stats = DelayStats(window)
    decoder = Decoder()
    failed: list[str] = []

    def on_raw(raw: Any) -> None:
        msg = decoder.decode(raw)
        stamp = getattr(getattr(msg, "header", None), "stamp", None)
        if stamp is None or not hasattr(stamp, "to_sec"):
            failed.append(f"{resolve_name(topic)}: {getattr(msg, '_type', 'the message')} does not have a header")
            return
        stats.on_message(time.time(), stamp.to_sec())

    def tick() -> None:
        if failed:
            raise MrosError(failed[0])
        text = stats.report()
        if text is not None:
            click.echo(text)

    async def main() -> None:
        await _measure(topic, on_raw, tick, duration)

    with contextlib.suppress(KeyboardInterrupt):
        run(main())


group.add_command(pub)
