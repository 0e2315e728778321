"""``mros graph``: watch nodes, topics and services appear and vanish.

``mros topic list --watch`` prints the topic lines of the same output (``print_changes``).
The watching itself is ``mrosd.master.client.watch_graph``: pushed by an mrosd master (its
``waitSystemStateChange`` extension), polled from any other master (``getSystemState``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import click

from mros_cli.main import CALL_TIMEOUT, master_client, run, slave_call
from mrosd.errors import MrosError

if TYPE_CHECKING:
    from mrosd.master.client import GraphChange, MasterClient


def format_change(change: GraphChange, *, as_json: bool) -> str:
    """One output line: ``+ topic /chatter [std_msgs/String]`` or a JSON object."""
    if as_json:
        record: dict[str, object] = {
            "time": round(time.time(), 6),
            "event": "appeared" if change.appeared else "vanished",
            "kind": change.kind,
            "name": change.name,
        }
        if change.kind == "topic":
            record["type"] = change.detail
        elif change.kind == "service":
            record["node"] = change.detail
        return json.dumps(record)
    sign = "+" if change.appeared else "-"
    if change.kind == "topic":
        return f"{sign} topic {change.name} [{change.detail}]"
    return f"{sign} {change.kind} {change.name}"


@click.group(name="graph")
def group() -> None:
    """Watch the ROS graph (nodes, topics, services) change.

    \b
    Examples:
      mros graph watch
      mros graph watch --json | jq .
    """


#: ``--poll``, shared by ``mros graph watch`` and ``mros topic list --watch``.
poll_option = click.option(
    "--poll",
    "poll",
    type=click.FloatRange(min=0.05),
    default=0.5,
    show_default=True,
    metavar="SECONDS",
    help="Polling period against masters that do not push changes (rosmaster).",
)


@group.command(name="watch")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per line (time, event, kind, name, ...).")
@poll_option
def watch(as_json: bool, poll: float) -> None:
    """Print nodes, topics and services as they appear (+) and vanish (-), starting with the current graph.

    Against an mrosd master changes are pushed as they happen; against rosmaster the graph is polled.
    Runs until interrupted (Ctrl-C).
    """
    run(print_changes(as_json=as_json, poll=poll))


def every_change(change: GraphChange) -> bool:
    """``print_changes``' default filter: keep everything."""
    return True


async def print_changes(*, as_json: bool, poll: float, keep: Callable[[GraphChange], bool] = every_change) -> None:
    """Print each change of the graph (those ``keep`` accepts), one line each, until cancelled.

    ``keep`` is a predicate, never None: mypy's narrowing of an optional callable captured by a comprehension
    differs between versions (``"object" not callable`` under one), and a default predicate needs none.
    """
    from mrosd.master.client import GraphSnapshot, graph_changes, watch_graph

    async with master_client() as client:
        previous = GraphSnapshot()
        async for graph in watch_graph(client, poll_interval=poll):
            lines = [
                format_change(change, as_json=as_json) for change in graph_changes(previous, graph) if keep(change)
            ]
            previous = graph
            if lines:
                click.echo("\n".join(lines))
                click.get_text_stream("stdout").flush()


def watch_topics(namespace: str | None, *, as_json: bool, poll: float) -> None:
    """``mros topic list --watch [NAMESPACE]``: the topic lines of ``mros graph watch``, under a resolved namespace."""
    prefix = namespace.rstrip("/") + "/" if namespace else "/"

    def keep(change: GraphChange) -> bool:
        return change.kind == "topic" and (
            namespace is None or change.name == namespace or change.name.startswith(prefix)
        )

    run(print_changes(as_json=as_json, poll=poll, keep=keep))


async def shared_memory_section(master: MasterClient, topic: str, publishers: list[str]) -> str:
    """``topic info``'s section listing the connections of ``topic`` that use shared memory.

    Asks each publisher's ``getBusInfo`` for ``SHMROS`` rows (mrosd nodes on one host). Empty when there are
    none, so the output stays rostopic's for every graph of rospy and roscpp nodes.
    """
    from mrosd.xmlrpc import XmlRpcClient

    lines: list[str] = []
    async with XmlRpcClient(timeout=CALL_TIMEOUT) as xmlrpc:
        for node in publishers:
            try:
                rows = await slave_call(xmlrpc, await master.lookup_node(node), "getBusInfo")
            except MrosError:
                continue  # gone or unreachable: topic info already listed it as it could
            for row in rows if isinstance(rows, list) else []:
                if isinstance(row, list) and len(row) >= 5 and row[2:5] == ["o", "SHMROS", topic]:
                    info = row[6] if len(row) >= 7 and isinstance(row[6], str) else ""
                    lines.append(f" * {node} -> {row[1]}" + (f" ({info})" if info else "") + "\n")
    return "Shared memory: \n" + "".join(lines) + "\n" if lines else ""
