"""``mros reconfigure``: list dynamic_reconfigure servers, get and set their values (as dynparam)."""

from __future__ import annotations

from typing import Any

import click

from mros_cli.main import EXIT_ERROR, anonymous, fail, master_client, resolve_name, run
from mros_cli.values import load_document

#: Bound on the description, the current config and the set call.
TIMEOUT = 5.0


@click.group(name="reconfigure")
def group() -> None:
    """List dynamic_reconfigure servers, get and set their parameters (like dynparam).

    \b
    Examples:
      mros reconfigure list
      mros reconfigure get /camera
      mros reconfigure set /camera exposure 20
      mros reconfigure set /camera "{exposure: 20, auto: false}"
    """


@group.command(name="list")
def list_() -> None:
    """Print the nodes that serve dynamic_reconfigure (a ``set_parameters`` service with descriptions).

    \b
    Example:
      mros reconfigure list
    """

    async def main() -> list[str]:
        async with master_client() as master:
            pubs, _subs, services = await master.get_system_state()
        topics = {str(t) for t, _nodes in pubs}
        found = []
        for name, _nodes in services:
            ns = str(name).removesuffix("/set_parameters")
            if ns != str(name) and f"{ns}/parameter_descriptions" in topics:
                found.append(ns)
        return sorted(found)

    names = run(main())
    if names:
        click.echo("\n".join(names))


async def _with_client(server: str, action: Any) -> Any:
    from mrosd.reconfigure import ReconfigureClient
    from mrosd.tcpros import Node

    async with master_client() as master:
        uri = master.master_uri
    async with (
        Node(anonymous("reconfigure"), master_uri=uri, argv=[]) as node,
        ReconfigureClient(node, server) as client,
    ):
        return await action(client)


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        import json

        return json.dumps(value)
    return repr(value)


@group.command()
@click.argument("node")
def get(node: str) -> None:
    """Print a server's current values as YAML, in its description's order.

    \b
    Example:
      mros reconfigure get /camera
    """
    ns = resolve_name(node)

    async def action(client: Any) -> tuple[list[str], dict[str, Any]]:
        description = await client.get_description(TIMEOUT)
        config = await client.get_configuration(TIMEOUT)
        return [p.name for p in description.params()], config

    order, config = run(_with_client(ns, action))
    names = order + [k for k in config if k not in order]
    click.echo("\n".join(f"{k}: {_yaml_value(config[k])}" for k in names if k in config))


@group.command(name="set")
@click.argument("node")
@click.argument("args", nargs=-1, required=True)
def set_(node: str, args: tuple[str, ...]) -> None:
    """Set values: ``KEY VALUE`` or one YAML mapping; types and ranges are checked against the description.

    \b
    Examples:
      mros reconfigure set /camera exposure 20
      mros reconfigure set /camera "{exposure: 20, mode: Large}"
    """
    ns = resolve_name(node)
    if len(args) == 2:
        value = load_document(args[1], "VALUE")
        changes = {args[0]: args[1] if value is None else value}
    elif len(args) == 1:
        doc = load_document(args[0], "YAML")
        if not isinstance(doc, dict) or not doc:
            fail("expected KEY VALUE or a YAML mapping such as '{int_: 3}'", 2)
        changes = {str(k): v for k, v in doc.items()}
    else:
        fail("expected KEY VALUE or a YAML mapping", 2)

    async def action(client: Any) -> dict[str, Any]:
        result: dict[str, Any] = await client.update_configuration(changes, TIMEOUT)
        return result

    config = run(_with_client(ns, action))
    adjusted = {k: config.get(k) for k in changes if config.get(k) != changes[k] and k in config}
    for key, value in adjusted.items():
        click.echo(f"{key}: {_yaml_value(value)}  # as the server set it", err=True)
    if any(k not in config for k in changes):
        fail("the server did not report every value set", EXIT_ERROR)
