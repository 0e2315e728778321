"""``mros service``: list, inspect, find and call services, printed as ``rosservice`` prints them.

``list`` and ``uri`` ask the master; ``type``, ``info``, ``args`` and ``find`` probe the server with a TCPROS
connection header (``probe=1``) and read the type it answers; ``call`` builds the request from YAML arguments
like ``rosservice call`` and prints the response in rostopic's YAML text. Exit codes are rosservice's: 2 when
a service to call (or whose args are asked) is not available, 1 for ``info`` of an unknown service.
"""

from __future__ import annotations

import contextlib
import sys
from typing import TYPE_CHECKING, Any

import click

from mros_cli.main import EXIT_ERROR, EXIT_USAGE, anonymous, fail, master_client, resolve_name, run
from mros_cli.values import build_message, parse_pub_args, printable_args
from mrosd.errors import MasterError, MrosError

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient


@click.group(name="service")
def group() -> None:
    """List, inspect and call services (like rosservice).

    \b
    Examples:
      mros service list
      mros service type /add_two_ints
      mros service call /add_two_ints "{a: 1, b: 2}"
      mros service info /add_two_ints
      mros service find std_srvs/Trigger
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
        async with master_client() as master:
            return await services(master)

    rows = sorted(run(main()))
    if namespace:
        ns = resolve_name(namespace)
        rows = [r for r in rows if r[0] == ns or r[0].startswith(ns.rstrip("/") + "/")]
    lines = [f"{name} {','.join(providers)}" if nodes else name for name, providers in rows]
    if lines:
        click.echo("\n".join(lines))


async def services(master: MasterClient) -> list[tuple[str, list[str]]]:
    """(service, [providing nodes]) from getSystemState, in the master's order."""
    state = await master.get_system_state()
    return [(str(name), [str(n) for n in providers]) for name, providers in state[2]]


@group.command()
@click.argument("service")
def uri(service: str) -> None:
    """Print the rosrpc:// URI of a service.

    \b
    Example:
      mros service uri /add_two_ints
    """

    name = resolve_name(service)

    async def main() -> str:
        async with master_client() as master:
            try:
                value: str = await master.lookup_service(name)
            except MasterError:
                click.echo(f"Unknown service: {name}", err=True)  # rosservice's line, without ERROR:
                sys.exit(EXIT_ERROR)
            return value

    click.echo(run(main()))


#: Bound on the probe connection and its answer.
PROBE_TIMEOUT = 5.0


async def probe_type(master: MasterClient, service: str) -> str:
    """The service's type, asked from the server itself with a ``probe=1`` connection header (as rosservice).

    Raises:
        MasterError: the service is not registered.
        ServiceError: the server cannot be reached or does not answer with a type.
    """
    from mros_cli.main import CALLER_ID
    from mrosd.tcpros.service import probe_service

    fields = await probe_service(master, service, CALLER_ID, PROBE_TIMEOUT)
    return fields["type"]


@group.command(name="type")
@click.argument("service")
def type_(service: str) -> None:
    """Print a service's type (asked from the server, as rosservice type).

    \b
    Example:
      mros service type /add_two_ints
    """
    name = resolve_name(service)

    async def main() -> str | None:
        async with master_client() as master:
            try:
                return await probe_type(master, name)
            except MasterError:
                return None

    found = run(main())
    if found is None:
        click.echo(f"Unknown service [{name}]", err=True)
        sys.exit(1)
    click.echo(found)


async def service_class(master: MasterClient, name: str) -> Any:
    """The service class of a registered service (its type probed from the server), or exit 2 as rosservice
    does when it is not available."""
    from mrosd.msg import get_service_class

    try:
        srv_type = await probe_type(master, name)
    except MasterError:
        fail(f"Service [{name}] is not available.", EXIT_USAGE)
    return get_service_class(srv_type)


@group.command()
@click.argument("service")
def args(service: str) -> None:
    """Print the request's field names (as rosservice args; nested fields as ``a.b``).

    \b
    Example:
      mros service args /add_two_ints
    """
    name = resolve_name(service)

    async def main() -> Any:
        async with master_client() as master:
            return await service_class(master, name)

    click.echo(" ".join(printable_args(run(main())._request_class)))


@group.command()
@click.argument("service")
def info(service: str) -> None:
    """Print a service's node, URI, type and request fields (as rosservice info).

    \b
    Example:
      mros service info /add_two_ints
    """
    name = resolve_name(service)

    async def main() -> tuple[str, str, str, str] | None:
        async with master_client() as master:
            node = next((providers[0] for s, providers in await services(master) if s == name and providers), None)
            if node is None:
                return None
            srv_uri: str = await master.lookup_service(name)
            cls = await service_class(master, name)
            return node, srv_uri, cls._type, " ".join(printable_args(cls._request_class))

    found = run(main())
    if found is None:
        click.echo("ERROR: unknown service", err=True)
        sys.exit(EXIT_ERROR)
    node, srv_uri, srv_type, fields = found
    click.echo(f"Node: {node}\nURI: {srv_uri}\nType: {srv_type}\nArgs: {fields}")


@group.command()
@click.argument("srv_type", metavar="TYPE")
def find(srv_type: str) -> None:
    """Print the services of a service type, in the master's order (each server is probed, as rosservice).

    \b
    Example:
      mros service find std_srvs/Trigger
    """

    async def main() -> list[str]:
        found: list[str] = []
        async with master_client() as master:
            for name, _providers in await services(master):
                with contextlib.suppress(MrosError):
                    if await probe_type(master, name) == srv_type:
                        found.append(name)
        return found

    click.echo("\n".join(run(main())))


#: How often ``call --wait`` asks the master whether the service is registered yet.
WAIT_POLL = 0.2


async def wait_for_service(master: MasterClient, name: str) -> None:
    """Until the master knows the service and its server answers a probe (rospy.wait_for_service's rule)."""
    import asyncio

    from mrosd.errors import ServiceError

    while True:
        try:
            await probe_type(master, name)
            return
        except (MasterError, ServiceError):
            await asyncio.sleep(WAIT_POLL)


@group.command()
@click.argument("service")
@click.argument("args", nargs=-1)
@click.option("--wait", is_flag=True, help="Wait for the service to be advertised before calling it.")
def call(service: str, args: tuple[str, ...], wait: bool) -> None:
    """Call a service with YAML arguments (a dict, or one value per request field) and print the response.

    A service that is not registered, or arguments that do not fit its request, are an error with exit
    code 2, as in rosservice; --wait waits for the service to appear instead.

    \b
    Examples:
      mros service call /add_two_ints "{a: 1, b: 2}"
      mros service call /add_two_ints 1 2
      mros service call --wait /reset
    """
    from mros_cli.output import TextRenderer
    from mrosd.tcpros import Node

    name = resolve_name(service)
    try:
        values = parse_pub_args(tuple("''" if a == "" else a for a in args))
    except MrosError as exc:
        fail(str(exc), EXIT_USAGE)  # rosservice exits 2 on arguments it cannot use

    async def main() -> Any:
        async with master_client() as master:
            if wait:
                await master.get_uri()  # as rosservice: no master is an error, not a wait
                await wait_for_service(master, name)
            srv = await service_class(master, name)
        try:
            request = build_message(srv._request_class, values if args else {})
        except MrosError as exc:  # rosservice's hint after the error: the request's fields
            fields = " ".join(printable_args(srv._request_class))
            fail(" ".join(str(exc).split()), EXIT_USAGE, hint=f"Service arguments are: [{fields}]")
        async with Node(anonymous("call"), master_uri=master.master_uri, argv=[]) as node:
            proxy = node.service_proxy(name, srv)
            try:
                return await proxy.call(request)
            finally:
                closer = getattr(proxy, "aclose", None)
                if closer is not None:
                    await closer()

    response = run(main())
    click.echo(TextRenderer().render(response))
