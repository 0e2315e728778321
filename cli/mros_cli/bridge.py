"""``mros bridge``: the daemon's web part alone, against any master (rosmaster included).

For a robot that runs roscore rather than mrosd, or to serve a second port with other allow-lists: the
same ``mrosd.web.server.WebServer`` the daemon runs, in the foreground until Ctrl-C.
"""

from __future__ import annotations

import asyncio

import click

from mros_cli.main import master_uri, run
from mrosd.errors import ConfigError, MrosError
from mrosd.web.access import DEFAULT_ASSETS


@click.command(name="bridge")
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="bind address, or several comma-separated (127.0.0.1,::1); any not loopback needs --token",
)
@click.option("--port", "foxglove_port", type=click.IntRange(0, 65535), default=8765, show_default=True)
@click.option(
    "--rosbridge-port", type=click.IntRange(-1, 65535), default=9090, show_default=True, help="rosbridge v2; -1: off"
)
@click.option("--token", envvar="MROSD_WEB_TOKEN", default="", help="clients must pass ?token=... ($MROSD_WEB_TOKEN)")
@click.option("--topics", multiple=True, default=["*"], show_default=True, help="allowed topic glob (repeatable)")
@click.option("--services", multiple=True, default=["*"], show_default=True, help="allowed service glob (repeatable)")
@click.option("--params", multiple=True, default=["*"], show_default=True, help="allowed parameter glob (repeatable)")
@click.option(
    "--assets",
    multiple=True,
    default=DEFAULT_ASSETS,
    help="allowed package:// asset URI glob (repeatable; default: meshes, textures, URDFs)",
)
@click.option("--name", default="mros_bridge", show_default=True, help="node name in the graph")
def group(
    *,
    host: str,
    foxglove_port: int,
    rosbridge_port: int,
    token: str,
    topics: tuple[str, ...],
    services: tuple[str, ...],
    params: tuple[str, ...],
    assets: tuple[str, ...],
    name: str,
) -> None:
    """Serve the ROS graph to browsers: Foxglove WebSocket (Foxglove, Lichtblick) and rosbridge v2 (roslib).

    \b
    Examples:
      mros bridge                                  # ws://127.0.0.1:8765/
      mros bridge --host 0.0.0.0 --token s3cret   # open ws://robot:8765/?token=s3cret
      mros bridge --host 127.0.0.1,::1             # both loopbacks, IPv4 and IPv6
      mros bridge --topics '/camera/*' --topics /tf
    """
    from mrosd.web.access import AccessPolicy
    from mrosd.web.server import WebServer

    policy = AccessPolicy(topics=topics, services=services, params=params, assets=assets, token=token)
    hosts = [h.strip() for h in host.split(",") if h.strip()]
    if not hosts:
        raise click.UsageError(f"--host names no address: {host!r}")
    try:
        policy.check_bind(hosts)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None

    async def serve() -> None:
        server = WebServer(
            master_uri(),
            host=hosts,
            port=foxglove_port,
            policy=policy,
            node_name=name,
            rosbridge_port=rosbridge_port if rosbridge_port >= 0 else None,
        )
        try:
            await server.start()
        except OSError as exc:  # a port in use: aiohttp's message names the address and port
            raise MrosError(f"cannot serve: {exc.strerror or exc}") from exc
        try:
            also = f", rosbridge {' '.join(server.rosbridge_urls)}" if server.rosbridge_port is not None else ""
            click.echo(f"serving {' '.join(server.urls)}{also} (master {master_uri()}); Ctrl-C to stop", err=True)
            await asyncio.Event().wait()
        finally:
            await server.aclose()

    run(serve())
