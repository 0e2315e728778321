"""``mros service``: list services, show their type, call them, printed as ``rosservice`` prints them.

``list`` and ``uri`` ask the master; ``type`` probes the server with a TCPROS connection header
(``probe=1``) and reads the type it answers; ``call`` builds the request from YAML arguments like
``rosservice call`` and prints the response in rostopic's YAML text.
"""

from __future__ import annotations

from typing import Any

import click

from mros_cli.main import Graph, run


@click.group(name="service")
def group() -> None:
    """List, inspect and call services (like rosservice).

    \b
    Examples:
      mros service list
      mros service type /add_two_ints
      mros service call /add_two_ints "{a: 1, b: 2}"
    """


@group.command(name="list")
@click.option("-n", "--nodes", is_flag=True, help="Also print the node that provides each service.")
@click.argument("namespace", required=False)
def list_(nodes: bool, namespace: str | None) -> None:
    """List the services registered with the master, sorted.

    \b
    Example:
      mros service list
    """

    async def main() -> list[Any]:
        async with Graph() as graph:
            state = await graph.master("getSystemState")
            services: list[Any] = state[2]
            return services

    rows = sorted(run(main()))
    if namespace:
        prefix = namespace.rstrip("/") + "/"
        rows = [r for r in rows if r[0].startswith(prefix)]
    lines = [f"{name} {' '.join(providers)}" if nodes else name for name, providers in rows]
    if lines:
        click.echo("\n".join(lines))


@group.command()
@click.argument("service")
def uri(service: str) -> None:
    """Print the rosrpc:// URI of a service.

    \b
    Example:
      mros service uri /add_two_ints
    """

    async def main() -> str:
        async with Graph() as graph:
            value: str = await graph.master("lookupService", service)
            return value

    click.echo(run(main()))
