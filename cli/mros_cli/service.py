"""``mros service``: list services, show their type, call them, printed as ``rosservice`` prints them.

``list`` and ``uri`` ask the master; ``type`` probes the server with a TCPROS connection header
(``probe=1``) and reads the type it answers; ``call`` builds the request from YAML arguments like
``rosservice call`` and prints the response in rostopic's YAML text.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import click

from mros_cli.main import master_client, run

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
            state = await master.get_system_state()
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
        async with master_client() as master:
            value: str = await master.lookup_service(service)
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
    import asyncio
    import struct
    import urllib.parse

    from mros_cli.main import CALLER_ID
    from mrosd.errors import ServiceError
    from mrosd.tcpros.header import MAX_HEADER_SIZE, decode_header, encode_header

    uri: str = await master.lookup_service(service)
    parsed = urllib.parse.urlsplit(uri)
    if parsed.scheme != "rosrpc" or not parsed.hostname or parsed.port is None:
        raise ServiceError(f"service {service}: the master gave an unusable URI {uri!r}")
    header = encode_header({"callerid": CALLER_ID, "service": service, "md5sum": "*", "probe": "1"})
    try:
        async with asyncio.timeout(PROBE_TIMEOUT):
            reader, writer = await asyncio.open_connection(parsed.hostname, parsed.port)
            try:
                writer.write(header)
                (size,) = struct.unpack("<I", await reader.readexactly(4))
                if size > MAX_HEADER_SIZE:
                    raise ServiceError(f"service {service}: header of {size} bytes is too big")
                fields = decode_header(await reader.readexactly(size))
            finally:
                writer.close()
    except (OSError, TimeoutError, asyncio.IncompleteReadError) as exc:
        raise ServiceError(f"service {service}: cannot probe {uri}: {exc or type(exc).__name__}") from exc
    if "error" in fields:
        raise ServiceError(f"service {service}: {fields['error']}")
    if not fields.get("type"):
        raise ServiceError(f"service {service}: the server did not say its type")
    return fields["type"]


@group.command(name="type")
@click.argument("service")
def type_(service: str) -> None:
    """Print a service's type (asked from the server, as rosservice type).

    \b
    Example:
      mros service type /add_two_ints
    """
    import sys

    from mros_cli.param import resolve
    from mrosd.errors import MasterError

    name = resolve(service)

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


@group.command()
@click.argument("service")
@click.argument("args", nargs=-1)
def call(service: str, args: tuple[str, ...]) -> None:
    """Call a service with YAML arguments (a dict, or one value per request field) and print the response.

    \b
    Examples:
      mros service call /add_two_ints "{a: 1, b: 2}"
      mros service call /add_two_ints 1 2
      mros service call /reset
    """
    from mros_cli.output import TextRenderer
    from mros_cli.param import resolve
    from mros_cli.topic import anonymous, build_message, parse_pub_args
    from mrosd.msg import get_service_class
    from mrosd.tcpros import Node

    name = resolve(service)
    values = parse_pub_args(tuple("''" if a == "" else a for a in args))

    async def main() -> Any:
        async with master_client() as master:
            srv_type = await probe_type(master, name)
        srv = get_service_class(srv_type)
        request = build_message(srv._request_class, values if args else {})
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
