"""``mros web``: the URL of the page mrosd serves (graph, topics, live values, plots, images).

The page is on the daemon's Foxglove port. The URL comes from the running daemon of ``$ROS_MASTER_URI``
(its status file, ``mrosd.runstatus``: the port it actually bound, or why its web part failed, then exit
1); only when no daemon of this host serves that master is it computed from the configuration (``[web]``
in mrosd.toml, or ``$MROSD_WEB_*``), with a warning. The URL carries the token when one is configured,
since the page passes it on to its WebSocket. A loopback-only daemon on a robot is reached through an SSH
tunnel: ``ssh -L 8765:127.0.0.1:8765 robot``.
"""

from __future__ import annotations

import socket

import click

from mrosd.errors import ConfigError

#: Seconds to wait for the port to accept a connection (only to warn when nothing listens there).
PROBE_TIMEOUT = 1.0


def page_url(host: str, port: int, token: str) -> str:
    """The URL to open for a daemon serving its web part on ``host:port`` (0.0.0.0/:: as this host's name)."""
    if host in ("0.0.0.0", "::", ""):
        host = socket.gethostname()
    shown = f"[{host}]" if ":" in host else host
    query = f"?token={token}" if token else ""
    return f"http://{shown}:{port}/{query}"


@click.command(name="web")
@click.option("--config", "config_path", default=None, help="mrosd.toml to read (default: as mrosd does)")
def group(config_path: str | None) -> None:
    """Print the URL of mrosd's page: the graph, topics with Hz and bandwidth, live values, plots, images.

    \b
    Example:
      mros web            # http://127.0.0.1:8765/
    """
    from mros_cli.daemon import daemon_status
    from mros_cli.main import fail, master_uri
    from mrosd.config import load_config

    try:
        cfg = load_config(config_path)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    web = cfg.web
    st = daemon_status(master_uri())
    if st is not None:
        if "web" in st.failed:
            fail(f"the daemon's web part failed to start: {st.failed['web']}")
        if st.web is None:
            fail("the daemon's web part is off ([web] enabled = false): no page is served")
        query = f"?token={web.token}" if st.web.token_required and web.token else ""
        click.echo(st.web.page + query)
        if st.web.token_required and not web.token:
            click.echo("note: the daemon asks for a token: add ?token=... ([web] token in mrosd.toml)", err=True)
        return
    if not web.enabled:
        raise click.ClickException("the daemon's web part is off ([web] enabled = false): no page is served")
    host = web.hosts()[0]  # the daemon's URLs name its first address too
    click.echo(page_url(host, web.foxglove_port, web.token))
    click.echo(f"warning: no running mrosd serves {master_uri()} on this host; URL from the configuration", err=True)
    probe_host = "127.0.0.1" if host in ("0.0.0.0", "") else ("::1" if host == "::" else host)
    try:
        with socket.create_connection((probe_host, web.foxglove_port), timeout=PROBE_TIMEOUT):
            pass
    except OSError as exc:
        click.echo(f"warning: nothing answers on {probe_host}:{web.foxglove_port} ({exc}); is mrosd running?", err=True)
