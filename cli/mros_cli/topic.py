"""``mros topic``: list, inspect, echo, publish and measure topics, with rostopic's output.

``list``, ``info`` and ``type`` only ask the master. ``echo``, ``hz`` and ``bw`` subscribe in raw mode
(``AnyMsg``) so they need no local definition of the type: echo builds the class from the publisher's
``message_definition`` (``mrosd.msg.load_type``), the way a ROS user wishes rostopic did. ``pub`` parses
YAML arguments as rostopic does (one dictionary, or one value per field in order) and checks every value
against the field's ROS type, naming the field when it is wrong.

Output writes are coalesced: messages rendered in one event-loop turn leave in one ``write``, which is how
echo keeps up with fast topics (rostopic flushes after every message).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import math
import os
import sys
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import click
import yaml

from mros_cli.main import master_client, master_uri, run
from mros_cli.output import SEPARATOR, JsonRenderer, TextRenderer, extract_field
from mrosd.errors import MrosError
from mrosd.msg import Duration, Time, get_message_class, load_type
from mrosd.msg.spec import INT_RANGES

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient

_SEPARATOR_BYTES = SEPARATOR.encode()

#: rostopic pub -1 keeps its latched message up this long so that subscribers can connect.
ONCE_DELAY = 3.0
#: rostopic hz's default window ("-1": effectively everything).
HZ_WINDOW = 50000
#: rostopic bw's default window.
BW_WINDOW = 100
#: How often echo/hz/bw look for a topic that is not published yet.
TOPIC_POLL = 0.5


def resolve(name: str) -> str:
    """A topic name resolved like rostopic (relative to $ROS_NAMESPACE); a trailing ``/`` is dropped."""
    from mros_cli.param import resolve as resolve_name

    return resolve_name(name)


def anonymous(name: str) -> str:
    """rostopic's anonymous node names: ``/mros_<pid>_<ms>``."""
    return f"mros_{name}_{os.getpid()}_{int(time.time() * 1000)}"


async def topic_types(master: MasterClient) -> dict[str, str]:
    """Topic -> type for every topic the master knows (published or subscribed)."""
    pairs = await master.get_topic_types()
    return {str(t): str(ty) for t, ty in pairs}


def split_topic(name: str, types: dict[str, str]) -> tuple[str, str, list[str]] | None:
    """``/topic/field/sub`` -> (topic, type, [field, sub]) by exact, else longest-prefix, match."""
    if name in types:
        return name, types[name], []
    candidates = sorted((t for t in types if name.startswith(t.rstrip("/") + "/")), key=len, reverse=True)
    if not candidates:
        return None
    topic = candidates[0]
    fields = [f for f in name[len(topic) :].split("/") if f]
    return topic, types[topic], fields


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


def _header_value(header: Any, key: str) -> str:
    if isinstance(header, dict):
        return str(header.get(key, ""))
    value = getattr(header, key, None)
    if value is None:
        extra = getattr(header, "extra", None) or {}
        value = extra.get(key, "")
    return str(value)


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
    """


# --- master-only commands -----------------------------------------------------------------------------


@group.command(name="list")
@click.option("-v", "--verbose", is_flag=True, help="Print types and publisher/subscriber counts.")
@click.option("-p", "publishers_only", is_flag=True, help="Only published topics.")
@click.option("-s", "subscribers_only", is_flag=True, help="Only subscribed topics.")
@click.argument("namespace", required=False)
def list_(verbose: bool, publishers_only: bool, subscribers_only: bool, namespace: str | None) -> None:
    """List the topics the master knows, sorted (``-v`` as ``rostopic list -v``).

    \b
    Examples:
      mros topic list
      mros topic list -v
    """
    if publishers_only and subscribers_only:
        raise click.UsageError("give only one of -p and -s")

    async def main() -> tuple[tuple[Any, ...], dict[str, str]]:
        async with master_client() as master:
            state = await master.get_system_state()
            return state, await topic_types(master)

    state, types = run(main())
    pubs = [(t, types.get(t, "unknown type"), n) for t, n in state[0]]
    subs = [(t, types.get(t, "unknown type"), n) for t, n in state[1]]
    if namespace:
        ns = resolve(namespace)
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
    """Print a topic's type, publishers and subscribers.

    \b
    Example:
      mros topic info /chatter
    """
    name = resolve(topic)

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
            return text + "\n"

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
    name = resolve(topic)

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
    click.echo(f"{msg_type} {'/'.join(fields)} {_field_type(msg_type, fields)}")


def _field_type(msg_type: str, fields: list[str]) -> str:
    current = msg_type
    for name in fields:
        cls = get_message_class("std_msgs/Header" if current == "Header" else current)
        table = dict(zip(cls.__struct_fields__, cls._field_types, strict=True))
        if name not in table:
            raise MrosError(f"{current} has no field {name!r}; its fields are: {', '.join(table)}")
        current = table[name]
    return current


# --- echo ---------------------------------------------------------------------------------------------


#: Pipe buffer asked for when stdout is a pipe: a 1 MB image prints ~3.6 MB, which through Linux's default
#: 64 KiB pipe costs ~60 writer/reader wake-ups per frame.
PIPE_SIZE = 1 << 20


def _grow_pipe(out: Any) -> None:
    """Enlarge stdout's pipe buffer (Linux ``F_SETPIPE_SZ``); silently keep the default where not allowed."""
    import fcntl
    import stat

    setpipe = getattr(fcntl, "F_SETPIPE_SZ", None)
    try:
        fd = out.fileno()
        if setpipe is None or not stat.S_ISFIFO(os.fstat(fd).st_mode):
            return
        fcntl.fcntl(fd, setpipe, PIPE_SIZE)
    except (OSError, ValueError, AttributeError):
        return


class Echo:
    """Decodes raw messages with the publisher's own definition and writes them, coalesced per loop turn."""

    def __init__(self, fields: list[str], count: int | None, *, noarr: bool, as_json: bool, offset: bool) -> None:
        self.fields = fields
        self.count = count
        self.shown = 0
        self.offset = offset
        self.text = TextRenderer(noarr=noarr)
        self.json = JsonRenderer() if as_json else None
        self.done = asyncio.Event()
        self.error: BaseException | None = None
        self._classes: dict[tuple[str, str], Any] = {}
        self._pending: list[bytes] = []
        self._flush_scheduled = False
        self._out = sys.stdout.buffer
        _grow_pipe(self._out)
        self._field_type: str | None = None

    def _class_for(self, header: Any) -> Any:
        msg_type = _header_value(header, "type")
        md5 = _header_value(header, "md5sum")
        cls = self._classes.get((msg_type, md5))
        if cls is None:
            cls = load_type(msg_type, _header_value(header, "message_definition"))
            self._classes[(msg_type, md5)] = cls
        return cls

    def on_raw(self, raw: Any) -> None:
        """Subscriber callback: decode, render, queue for the coalesced write."""
        if self.done.is_set():
            return
        try:
            cls = self._class_for(raw.header)
            msg = cls.deserialize(raw.data)
            value = extract_field(msg, self.fields) if self.fields else msg
            if self.json is not None:
                self._pending.append(self.json.render(value) + b"\n")
            else:
                if self.offset:
                    self.text.offset_ns = time.time_ns()
                type_info = self._type_info(cls) if self.fields else None
                self._pending.extend(self.text.render_chunks(value, type_info))
                self._pending.append(_SEPARATOR_BYTES)
        except (MrosError, KeyError) as exc:
            self.error = exc
            self.done.set()
            return
        self.shown += 1
        if self.count is not None and self.shown >= self.count:
            self.flush()
            self.done.set()
        elif not self._flush_scheduled:
            self._flush_scheduled = True
            asyncio.get_running_loop().call_soon(self.flush)

    def _type_info(self, cls: Any) -> str | None:
        if self._field_type is None:
            try:
                self._field_type = _field_type(cls._type, [f.split("[", 1)[0] for f in self.fields])
            except MrosError:
                self._field_type = ""
        return self._field_type or None

    def flush(self) -> None:
        """Write everything rendered so far: a burst of small messages as one joined write, a few big
        pieces (an image's ``uint8[]`` text) through the buffered writer as they are, never copied again."""
        self._flush_scheduled = False
        if not self._pending:
            return
        data = self._pending if len(self._pending) < 64 else [b"".join(self._pending)]
        self._pending = []
        try:
            self._out.writelines(data)
            self._out.flush()
        except BrokenPipeError:
            self.done.set()


@group.command()
@click.argument("topic")
@click.option("-n", "count", type=click.IntRange(min=1), help="Exit after N messages.")
@click.option("--noarr", is_flag=True, help="Show arrays as <array type: T, length: N>.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per line instead of YAML text.")
@click.option("--offset", is_flag=True, help="Print time fields as offsets from the current time.")
def echo(topic: str, count: int | None, noarr: bool, as_json: bool, offset: bool) -> None:
    """Print messages as rostopic echo does (``---`` after each); ``/topic/field`` prints one field.

    The type need not be known locally: it is built from the publisher's message definition.

    \b
    Examples:
      mros topic echo /chatter
      mros topic echo /odom/pose/pose/position -n 1
      mros topic echo /scan --noarr
      mros topic echo /chatter --json
    """
    name = resolve(topic)

    async def main() -> None:
        async with master_client() as master:
            real, _type, fields = await wait_for_topic(master, name)
        echo = Echo(fields, count, noarr=noarr, as_json=as_json, offset=offset)
        from mrosd.tcpros import AnyMsg, Node  # aiohttp and the TCPROS stack: only when a node is needed

        async with Node(anonymous("echo"), master_uri=master.master_uri, argv=[]) as node:
            await node.subscribe(real, AnyMsg, callback=echo.on_raw)
            await echo.done.wait()
            echo.flush()
        if echo.error is not None:
            raise MrosError(f"cannot show {name}: {echo.error}")

    run(main())


# --- pub ----------------------------------------------------------------------------------------------



def _class(rostype: str) -> Any:
    return get_message_class("std_msgs/Header" if rostype == "Header" else rostype)


def _time_value(rostype: str, value: Any, where: str) -> Any:
    kind = Time if rostype == "time" else Duration
    if value == "now" and rostype == "time":
        return Time.now()
    if isinstance(value, dict):
        unknown = set(value) - {"secs", "nsecs"}
        if unknown:
            raise MrosError(f"field {where}: unknown key {sorted(unknown)[0]!r} (a {rostype} has secs and nsecs)")
        return kind(int(value.get("secs", 0)), int(value.get("nsecs", 0)))
    if isinstance(value, int | float) and not isinstance(value, bool):
        return kind.from_sec(float(value)) if hasattr(kind, "from_sec") else kind(int(value), 0)
    raise MrosError(f"field {where}: expected {rostype} ({{secs: S, nsecs: N}}, seconds or 'now'), got {value!r}")


def _scalar(rostype: str, value: Any, where: str) -> Any:
    if rostype in INT_RANGES:
        if isinstance(value, bool) or not isinstance(value, int):
            raise MrosError(f"field {where}: expected {rostype}, got {type(value).__name__} {value!r}")
        low, high = INT_RANGES[rostype]
        if not low <= value <= high:
            raise MrosError(f"field {where}: {value} is out of range for {rostype} ({low}..{high})")
        return value
    if rostype in ("float32", "float64"):
        if isinstance(value, bool) or not isinstance(value, int | float):
            if isinstance(value, str) and value.strip().lower() in ("nan", "inf", "-inf", ".nan", ".inf", "-.inf"):
                return float(value.strip().lower().replace(".", ""))
            raise MrosError(f"field {where}: expected {rostype}, got {type(value).__name__} {value!r}")
        return float(value)
    if rostype == "bool":
        if isinstance(value, bool) or value in (0, 1):
            return bool(value)
        raise MrosError(f"field {where}: expected bool, got {type(value).__name__} {value!r}")
    if rostype == "string":
        if isinstance(value, bool | int | float):
            return str(value)
        if not isinstance(value, str):
            raise MrosError(f"field {where}: expected string, got {type(value).__name__} {value!r}")
        return value
    if rostype in ("time", "duration"):
        return _time_value(rostype, value, where)
    return build_message(_class(rostype), value, where)


def _field_value(rostype: str, value: Any, where: str) -> Any:
    if "[" not in rostype:
        return _scalar(rostype, value, where)
    element, _, size = rostype.partition("[")
    size = size.rstrip("]")
    if element in ("uint8", "char") and isinstance(value, str | bytes):
        data = value.encode("latin-1") if isinstance(value, str) else value
        items: list[Any] = list(data)
    elif isinstance(value, list | tuple):
        items = list(value)
    else:
        raise MrosError(f"field {where}: expected a list for {rostype}, got {type(value).__name__} {value!r}")
    if size and len(items) != int(size):
        raise MrosError(f"field {where}: {rostype} needs exactly {size} items, got {len(items)}")
    converted = [_scalar(element, item, f"{where}[{i}]") for i, item in enumerate(items)]
    if element in ("uint8", "char"):
        return bytes(converted)
    return converted


def build_message(cls: Any, value: Any, where: str = "") -> Any:
    """A message of class ``cls`` from a YAML value: a dict by field name, or a list of fields in order.

    ``'now'`` fills a time with the current time and ``'auto'`` a Header with a stamp of now, as rostopic.

    Raises:
        MrosError: a field is unknown, missing from a positional list, or has the wrong type or range;
            the message names the field (``pose.position.x``).
    """
    names: tuple[str, ...] = cls.__struct_fields__
    types: tuple[str, ...] = tuple(cls._field_types)
    prefix = f"{where}." if where else ""
    if value == "auto" and getattr(cls, "_type", "") == "std_msgs/Header":
        value = {"stamp": "now"}
    if value is None:
        value = {}
    if isinstance(value, list | tuple):
        if len(value) != len(names):
            raise MrosError(
                f"{where or cls._type}: got {len(value)} values for {len(names)} fields ({', '.join(names)})"
            )
        value = dict(zip(names, value, strict=True))
    if not isinstance(value, dict):
        if len(names) == 1:
            value = {names[0]: value}
        else:
            fields = ", ".join(names)
            raise MrosError(f"{where or cls._type}: expected a dictionary of fields ({fields}), got {value!r}")
    table = dict(zip(names, types, strict=True))
    kwargs: dict[str, Any] = {}
    for key, item in value.items():
        if key not in table:
            raise MrosError(f"field {prefix}{key}: {cls._type} has no such field; its fields are: {', '.join(names)}")
        kwargs[key] = _field_value(table[key], item, f"{prefix}{key}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError, MrosError) as exc:
        raise MrosError(f"{where or cls._type}: {exc}") from exc


def parse_pub_args(args: tuple[str, ...]) -> Any:
    """rostopic pub's argument rules: one YAML dict, or one YAML value per field."""
    values: list[Any] = []
    for arg in args:
        try:
            values.append(yaml.safe_load(arg))
        except yaml.YAMLError as exc:
            raise MrosError(f"argument {arg!r} is not valid YAML: {' '.join(str(exc).split())}") from exc
    if len(values) == 1 and (isinstance(values[0], dict) or values[0] is None):
        return values[0]
    return values


#: -f/stdin input without -r, -l or -1 is published at this rate, as rostopic does.
STREAM_RATE = 10.0
#: How long -f/stdin publishing waits for a first subscriber before it starts (rostopic: 5 s).
STREAM_SUBSCRIBER_WAIT = 5.0


def stdin_is_input() -> bool:
    """Whether stdin is piped or redirected from a file (a terminal or /dev/null is not message input)."""
    import stat

    try:
        mode = os.fstat(sys.stdin.fileno()).st_mode
    except (OSError, ValueError, AttributeError):
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISREG(mode)


def file_documents(path: str) -> list[Any]:
    """Every YAML document in ``path`` (``---``-separated, like a rostopic -f file); empty ones are skipped.

    Raises:
        MrosError: the file cannot be read or is not valid YAML (nothing is published then).
    """
    try:
        with open(path, encoding="utf-8") as stream:
            docs = list(yaml.safe_load_all(stream))
    except OSError as exc:
        raise MrosError(f"cannot read {path}: {exc.strerror or exc}") from exc
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MrosError(f"invalid YAML in {path}: {' '.join(str(exc).split())}") from exc
    return [d for d in docs if d is not None]


def load_document(text: str, where: str) -> Any:
    """One YAML document from stdin; ``None`` when it is empty."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise MrosError(f"invalid YAML in {where}: {' '.join(str(exc).split())}") from exc


@group.command()
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
    name = resolve(topic)
    cls = _class(msg_type)
    from_stdin = path == "-" or (path is None and not args and bool(cls.__struct_fields__) and stdin_is_input())
    if path is not None and path != "-":
        docs = [build_message(cls, d) for d in file_documents(path)]
        for m in docs:
            m.serialize()  # every message is checked before the first one is published
        _publish_stream(name, cls, iter_list(docs), rate, once, latch, count, repeat_single=len(docs) == 1)
        return
    if from_stdin:
        _publish_stream(name, cls, None, rate, once, latch, count, repeat_single=False)
        return
    msg = build_message(cls, parse_pub_args(args))
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


async def iter_list(items: list[Any]) -> Any:
    """An async iterator over ``items`` (file input is loaded and checked up front)."""
    for item in items:
        yield item


#: Lines read ahead from stdin; the reader thread waits (nothing is dropped) while the publisher catches up.
STDIN_QUEUE = 256


def _start_stdin_reader(loop: asyncio.AbstractEventLoop, queue: asyncio.Queue[str]) -> None:
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


async def _stdin_messages(cls: Any) -> Any:
    """Messages from stdin, one per ``---``-terminated YAML document, as they arrive."""
    queue: asyncio.Queue[str] = asyncio.Queue(maxsize=STDIN_QUEUE)
    _start_stdin_reader(asyncio.get_running_loop(), queue)
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
        source = messages if messages is not None else _stdin_messages(cls)
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


class RateStats:
    """rostopic hz's statistics over the inter-arrival times of a bounded window."""

    def __init__(self, window: int) -> None:
        self.deltas: deque[float] = deque(maxlen=max(window - 1, 1))
        self.last: float | None = None
        self.last_printed: float | None = None

    def on_message(self, now: float) -> None:
        """Record one arrival at wall time ``now``."""
        if self.last is not None and now >= self.last:
            self.deltas.append(now - self.last)
        elif self.last is not None:
            self.deltas.clear()
        self.last = now

    def report(self) -> str:
        """The two lines rostopic hz prints each second, or ``no new messages``."""
        if not self.deltas or self.last == self.last_printed:
            return "no new messages"
        self.last_printed = self.last
        n = len(self.deltas)
        mean = sum(self.deltas) / n
        rate = 1.0 / mean if mean > 0 else 0.0
        std = math.sqrt(sum((d - mean) ** 2 for d in self.deltas) / n)
        return (
            f"average rate: {rate:.3f}\n\tmin: {min(self.deltas):.3f}s max: {max(self.deltas):.3f}s "
            f"std dev: {std:.5f}s window: {n + 1}"
        )


class BandwidthStats:
    """rostopic bw's statistics over the sizes of the last messages."""

    def __init__(self, window: int) -> None:
        self.times: deque[float] = deque(maxlen=window)
        self.sizes: deque[int] = deque(maxlen=window)

    def on_message(self, now: float, size: int) -> None:
        """Record one message of ``size`` body bytes."""
        self.times.append(now)
        self.sizes.append(size)

    def report(self, now: float) -> str | None:
        """rostopic bw's two lines, or None until two messages arrived."""
        if len(self.times) < 2:
            return None
        n = len(self.times)
        total = sum(self.sizes)
        per_s = total / max(now - self.times[0], 1e-9)
        values = [per_s, total / n, min(self.sizes), max(self.sizes)]
        if per_s < 1000:
            bw, mean, low, high = [f"{v:.2f}B" for v in values]
        elif per_s < 1000000:
            bw, mean, low, high = [f"{v / 1000:.2f}KB" for v in values]
        else:
            bw, mean, low, high = [f"{v / 1000000:.2f}MB" for v in values]
        return f"average: {bw}/s\n\tmean: {mean} min: {low} max: {high} window: {n}"


async def _measure(topic: str, on_raw: Any, tick: Any, duration: float | None) -> None:

    async with master_client() as master:
        real, _type, _fields = await wait_for_topic(master, resolve(topic))
    from mrosd.tcpros import AnyMsg, Node  # aiohttp and the TCPROS stack: only when a node is needed

    async with Node(anonymous("measure"), master_uri=master.master_uri, argv=[]) as node:
        await node.subscribe(real, AnyMsg, callback=on_raw)
        click.echo(f"subscribed to [{real}]")
        end = None if duration is None else time.monotonic() + duration
        while end is None or time.monotonic() < end:
            await asyncio.sleep(1.0)
            tick()


@group.command()
@click.argument("topic")
@click.option("-w", "--window", type=click.IntRange(min=2), default=HZ_WINDOW, show_default=True,
              help="Number of messages to average over.")  # fmt: skip
@click.option("--duration", type=float, help="Stop after this many seconds.")
def hz(topic: str, window: int, duration: float | None) -> None:
    """Print a topic's publishing rate every second (rostopic hz's format).

    \b
    Example:
      mros topic hz /camera/image -w 100
    """
    stats = RateStats(window)

    async def main() -> None:
        await _measure(topic, lambda _raw: stats.on_message(time.time()), lambda: click.echo(stats.report()), duration)

    with contextlib.suppress(KeyboardInterrupt):
        run(main())


@group.command()
@click.argument("topic")
@click.option("-w", "--window", type=click.IntRange(min=2), default=BW_WINDOW, show_default=True,
              help="Number of messages to average over.")  # fmt: skip
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
