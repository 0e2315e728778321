"""``mros action``: list, inspect, send goals to and cancel actionlib action servers.

An action server is recognised by its topics, as actionlib lays them out: ``NAME/status`` (a
``actionlib_msgs/GoalStatusArray``), ``NAME/result`` and ``NAME/feedback`` published, ``NAME/goal`` and
``NAME/cancel`` subscribed. ``send`` finds the action type from those topics' types when it is not given.
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import TYPE_CHECKING, Any

import click

from mros_cli.main import EXIT_ERROR, EXIT_INTERRUPTED, anonymous, fail, master_client, resolve_name, run
from mros_cli.values import build_message, load_document
from mrosd import backports

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient

STATUS_TYPE = "actionlib_msgs/GoalStatusArray"
#: Bound on waiting for the server's topics to connect (actionlib's clients wait as long as asked).
SERVER_TIMEOUT = 10.0
#: Bound on publishing the cancel when Ctrl-C interrupts ``send``.
CANCEL_TIMEOUT = 2.0


@click.group(name="action")
def group() -> None:
    """List, inspect, send goals to and cancel action servers (actionlib).

    \b
    Examples:
      mros action list
      mros action info /test_action
      mros action send /test_action "goal: 5"
      mros action cancel /test_action
    """


async def action_servers(master: MasterClient) -> dict[str, dict[str, Any]]:
    """NAME -> {type, servers, clients} for every NAME whose ``/status`` is a GoalStatusArray with publishers."""
    types = {str(name): str(t) for name, t in await master.get_topic_types()}
    pubs, subs, _ = await master.get_system_state()
    publishers = {str(t): [str(n) for n in nodes] for t, nodes in pubs}
    subscribers = {str(t): [str(n) for n in nodes] for t, nodes in subs}
    found: dict[str, dict[str, Any]] = {}
    for topic, servers in publishers.items():
        if not topic.endswith("/status") or types.get(topic) != STATUS_TYPE:
            continue
        name = topic[: -len("/status")]
        if f"{name}/result" not in publishers:
            continue
        found[name] = {
            "type": action_type_from(types, name),
            "servers": servers,
            "clients": publishers.get(f"{name}/goal", []),
            "goal_subscribers": subscribers.get(f"{name}/goal", []),
        }
    return found


def action_type_from(types: dict[str, str], name: str) -> str | None:
    """``pkg/NameAction`` from the type of ``NAME/goal``, ``NAME/result`` or ``NAME/feedback``."""
    for topic, suffix in (("goal", "ActionGoal"), ("result", "ActionResult"), ("feedback", "ActionFeedback")):
        t = types.get(f"{name}/{topic}", "")
        if t.endswith(suffix):
            return t[: -len(suffix)] + "Action"
    return None


@group.command(name="list")
def list_() -> None:
    """Print the action servers on the graph, sorted.

    \b
    Example:
      mros action list
    """

    async def main() -> dict[str, dict[str, Any]]:
        async with master_client() as master:
            return await action_servers(master)

    names = sorted(run(main()))
    if names:
        click.echo("\n".join(names))


@group.command()
@click.argument("name")
def info(name: str) -> None:
    """Print an action server's type, the nodes serving it and the clients sending it goals.

    \b
    Example:
      mros action info /test_action
    """
    ns = resolve_name(name)

    async def main() -> dict[str, Any] | None:
        async with master_client() as master:
            return (await action_servers(master)).get(ns)

    found = run(main())
    if found is None:
        fail(f"no action server at {ns}", EXIT_ERROR)
    lines = [f"Action: {ns}", f"Type: {found['type'] or 'unknown'}", "", "Servers:"]
    lines += [f" * {n}" for n in found["servers"]] + ["", "Clients:"]
    lines += [f" * {n}" for n in found["clients"]] or [" None"]
    click.echo("\n".join(lines))


async def find_type(ns: str) -> str:
    async with master_client() as master:
        types = {str(name): str(t) for name, t in await master.get_topic_types()}
    found = action_type_from(types, ns)
    if found is None:
        fail(f"cannot find the action type of {ns}: no {ns}/goal, /result or /feedback topic; give TYPE", EXIT_ERROR)
    return found


@group.command()
@click.argument("name")
@click.argument("args", nargs=-1, required=True)
@click.option(
    "--timeout", type=float, default=SERVER_TIMEOUT, show_default=True, help="Seconds to wait for the server."
)
def send(name: str, args: tuple[str, ...], timeout: float) -> None:
    """Send a goal (YAML) and print each feedback and the result as YAML; Ctrl-C cancels the goal.

    NAME [TYPE] YAML: TYPE (``pkg/NameAction`` or ``pkg/Name``) is found from the server's topics when left out.

    \b
    Examples:
      mros action send /test_action "goal: 5"
      mros action send /test_action actionlib/TestAction "{goal: 5}"
    """
    from mros_cli.output import TextRenderer
    from mrosd.actions import ActionClient, ActionSpec, Status
    from mrosd.tcpros import Node

    if len(args) > 2:
        fail("expected NAME [TYPE] YAML", 2)
    ns = resolve_name(name)
    text = args[-1]
    given = args[0] if len(args) == 2 else None
    renderer = TextRenderer()
    outcome: dict[str, Any] = {}

    async def main() -> None:
        action_type = given or await find_type(ns)
        spec = ActionSpec.load(action_type)
        goal_msg = build_message(spec.goal, load_document(text, "goal") or {})
        async with master_client() as master:
            uri = master.master_uri
        async with Node(anonymous("action"), master_uri=uri, argv=[]) as node, ActionClient(node, ns, spec) as client:
            try:
                await client.wait_for_server(timeout)
            except TimeoutError:
                fail(f"the action server {ns} did not connect within {timeout:g} s", EXIT_ERROR)
            goal = await client.send_goal(goal_msg)
            try:
                async for feedback in goal.feedback():
                    click.echo(f"feedback:\n{_indent(renderer.render(feedback))}\n---", nl=True)
                result = await goal
            except asyncio.CancelledError:
                with contextlib.suppress(Exception):
                    async with backports.timeout(CANCEL_TIMEOUT):
                        await goal.cancel()
                        await goal.wait(CANCEL_TIMEOUT)  # the server's answer, or the bound
                outcome["interrupted"] = True
                return
            outcome["status"] = goal.status
            outcome["text"] = goal.text
            outcome["result"] = result

    with contextlib.suppress(KeyboardInterrupt):
        run(main())
    if outcome.get("interrupted") or not outcome:
        click.echo("goal cancelled", err=True)
        raise SystemExit(EXIT_INTERRUPTED)
    status = outcome["status"]
    click.echo(f"status: {status.name}" + (f" ({outcome['text']})" if outcome["text"] else ""))
    if outcome["result"] is not None:
        click.echo(renderer.render(outcome["result"]))
    if status is not Status.SUCCEEDED:
        raise SystemExit(EXIT_ERROR)


def _indent(text: str) -> str:
    return "\n".join(f"  {line}" for line in text.splitlines())


@group.command()
@click.argument("name")
@click.option("--id", "goal_id", default="", help="Cancel only this goal id.")
@click.option("--before", type=float, default=None, help="Cancel the goals stamped at or before this time (s).")
def cancel(name: str, goal_id: str, before: float | None) -> None:
    """Cancel goals on an action server: one by id, all stamped before a time, or (by default) all.

    \b
    Examples:
      mros action cancel /test_action
      mros action cancel /test_action --id /client-1-1700000000.5
    """
    from mrosd.msg import Time, get_message_class
    from mrosd.tcpros import Node

    ns = resolve_name(name)
    goal_id_cls = get_message_class("actionlib_msgs/GoalID")
    stamp = Time.from_sec(before) if before is not None else Time()

    async def main() -> None:
        async with master_client() as master:
            uri = master.master_uri
        async with Node(anonymous("action"), master_uri=uri, argv=[]) as node:
            pub = await node.advertise(f"{ns}/cancel", goal_id_cls, queue_size=1)
            try:
                await pub.wait_for_subscribers(1, SERVER_TIMEOUT)
            except TimeoutError:
                fail(f"no action server subscribes to {ns}/cancel", EXIT_ERROR)
            await pub.publish(goal_id_cls(stamp=stamp, id=goal_id))
            await asyncio.sleep(0.2)  # let the frame leave before the node unregisters

    run(main())
