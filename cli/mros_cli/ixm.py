"""``mros ixm``: look at and use the IXM shared-memory registry (list, show, read, write).

No protocol logic lives here: every command is a few calls on ``mrosd.ixm.IxmClient``. The daemon's socket
comes from ``--socket``, else ``$MROSD_IXM_SOCKET``, else the default search of docs/architecture.md.
Values are written as YAML (``1.5``, ``[1, 2, 3]``, ``"text"``, ``{data: 2.0}`` for a message), as
``mros topic pub`` takes them; messages are printed as ``rostopic echo`` prints them.
"""

from __future__ import annotations

import json
import pwd
from typing import Any

import click

from mrosd.errors import IxmError, MrosError

__all__ = ["group"]


def _socket(ctx: click.Context) -> str:
    from mrosd.ixm.rundir import find_ixm_socket

    value = ctx.obj.get("ixm_socket") if isinstance(ctx.obj, dict) else None
    return str(value) if value else find_ixm_socket()


def _client(ctx: click.Context) -> Any:
    from mrosd.ixm import IxmClient

    return IxmClient(_socket(ctx), name="mros")


def _user(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def _shape(seg: Any) -> str:
    if seg.count:
        return f"{seg.type}[{seg.count}]"
    if seg.max_size and "/" not in seg.type and seg.type != "string":
        return f"{seg.type}[] (max {seg.max_size} B)"
    if seg.max_size:
        return f"{seg.type} (max {seg.max_size} B)"
    return str(seg.type)


def _render(value: Any, type_name: str) -> str:
    if value is None:
        return "(never written)"
    if "/" in type_name:
        from mros_cli.output import TextRenderer

        return TextRenderer().render(value)
    if isinstance(value, bytes):
        from mros_cli.output import uint8_text

        return uint8_text(value)
    return str(value)


@click.group(name="ixm")
@click.option(
    "--socket",
    "socket_path",
    envvar="MROSD_IXM_SOCKET",
    metavar="PATH",
    help="IXM daemon socket (default: $MROSD_IXM_SOCKET, /run/mrosd/ixm.sock, ...).",
)
@click.pass_context
def group(ctx: click.Context, socket_path: str | None) -> None:
    """Shared-memory keys (IXM): list, show, read and write them.

    \b
    Examples:
      mros ixm list
      mros ixm show /arm/joints
      mros ixm read /arm/joints --follow
      mros ixm write /speed 1.5 --type float64
      mros ixm write /pose "{position: {x: 1.0}}" --type geometry_msgs/Pose
    """
    ctx.ensure_object(dict)
    ctx.obj["ixm_socket"] = socket_path


@group.command("list")
@click.option("-v", "--verbose", is_flag=True, help="Also list the connected processes.")
@click.option("--json", "as_json", is_flag=True, help="Print the daemon's lists as JSON.")
@click.pass_context
def list_(ctx: click.Context, verbose: bool, as_json: bool) -> None:
    """List the keys (and with -v the processes) you may open; root sees every key."""
    import msgspec

    with _client(ctx) as ixm:
        listing = ixm.list()
    if as_json:
        click.echo(json.dumps(msgspec.to_builtins(listing), indent=2))
        return
    for seg in listing.segments:
        click.echo(
            f"{seg.key}  {_shape(seg)}  {seg.capacity} B  readers: {len(seg.readers)}  writers: {len(seg.writers)}"
        )
    if verbose:
        click.echo("")
        for proc in sorted(listing.processes, key=lambda p: p.pid):
            if proc.name == "mros" and not proc.keys:
                continue  # this command itself
            keys = ", ".join(f"{k} ({m})" for k, m in sorted(proc.keys.items())) or "-"
            click.echo(f"pid {proc.pid}  {proc.name}  user {_user(proc.uid)}  keys: {keys}")


@group.command("show")
@click.argument("key")
@click.pass_context
def show(ctx: click.Context, key: str) -> None:
    """Show a key's type, size, segment, creator, readers and writers."""
    with _client(ctx) as ixm:
        listing = ixm.list(key)
    if not listing.segments:
        raise IxmError(f"no key {key} (nobody holds it open)")
    seg = listing.segments[0]
    names = {p.pid: p.name for p in listing.processes}
    click.echo(f"key: {seg.key}")
    click.echo(f"type: {_shape(seg)}")
    click.echo(f"capacity: {seg.capacity} bytes")
    click.echo(f"segment: {seg.shm_name}")
    click.echo(f"creator: {_user(seg.creator_uid)}")
    for role, pids in (("readers", seg.readers), ("writers", seg.writers)):
        click.echo(f"{role}:")
        for pid in pids:
            click.echo(f" * pid {pid} ({names.get(pid, '?')})")


@group.command("read")
@click.argument("key")
@click.option("-f", "--follow", is_flag=True, help="Keep printing each new value as it is written.")
@click.option("-n", "count", type=click.IntRange(min=1), help="With --follow: stop after COUNT values.")
@click.option("--timeout", type=float, default=None, help="With --follow: give up after SECONDS without a write.")
@click.pass_context
def read(ctx: click.Context, key: str, follow: bool, count: int | None, timeout: float | None) -> None:
    """Print a key's latest value (woken by writes with --follow; no polling)."""
    with _client(ctx) as ixm:
        handle = ixm.open(key, mode="r")
        type_name = handle.type.name
        if not follow:
            click.echo(_render(handle.read(), type_name))
            return
        shown = 0
        value = handle.read()
        if value is not None:
            click.echo(_render(value, type_name))
            click.echo("---")
            shown += 1
        while count is None or shown < count:
            try:
                value = handle.wait(timeout)
            except TimeoutError as exc:
                raise IxmError(f"no write to {key} within {timeout} s") from exc
            click.echo(_render(value, type_name))
            click.echo("---")
            shown += 1


@group.command("write")
@click.argument("key")
@click.argument("value")
@click.option("--type", "type_name", metavar="TYPE", help="Type to create the key with (float64, pkg/Msg, ...).")
@click.option("--count", type=click.IntRange(min=1), help="Create a fixed array of COUNT elements.")
@click.option("--max-size", type=click.IntRange(min=1), help="Create a bounded value of at most BYTES.")
@click.option("--hold", is_flag=True, help="Keep the key open (and its value alive) until interrupted.")
@click.pass_context
def write(  # noqa: PLR0917  (one parameter per click option)
    ctx: click.Context,
    key: str,
    value: str,
    type_name: str | None,
    count: int | None,
    max_size: int | None,
    hold: bool,
) -> None:
    """Write VALUE (YAML) to KEY; the key is created with --type if nobody holds it.

    A key lives while some process holds it: without --hold, a key that only this command held is freed
    when it exits (as IxmFree frees the last holder's segment).
    """
    import yaml

    try:
        data = yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise MrosError(f"VALUE is not valid YAML: {exc}") from exc
    with _client(ctx) as ixm:
        handle = ixm.open(key, type_name, count=count, max_size=max_size, mode="w")
        t = handle.type
        if t.is_message:
            from mros_cli.values import build_message
            from mrosd.msg import get_message_class

            data = build_message(get_message_class(t.name), data)
        elif t.name == "string" and not isinstance(data, str):
            data = value
        elif t.name in ("float32", "float64") and isinstance(data, list):
            data = [float(x) if isinstance(x, int) else x for x in data]
        handle.write(data)
        if hold:
            import signal

            stops = {signal.SIGINT, signal.SIGTERM}
            # blocked before the line is printed: a signal sent as soon as it is read waits for sigwait,
            # instead of hitting Python's default SIGINT handler (a KeyboardInterrupt, status 130)
            signal.pthread_sigmask(signal.SIG_BLOCK, stops)  # SIGTERM too goes to sigwait, not to its default
            click.echo(f"holding {key}; Ctrl-C to release", err=True)
            signal.sigwait(stops)  # (death): the key is released below, as on Ctrl-C
