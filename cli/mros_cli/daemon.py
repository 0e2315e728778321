"""``mros daemon``: is mrosd (or any ROS master) up, and what does it hold.

``status`` asks the master for its pid, URI and graph size, and checks whether the IXM registry's socket
accepts connections; exit code 0 when the master answers, 1 otherwise, so scripts can wait on it.
"""

from __future__ import annotations

import asyncio
import os
import socket
import sys
import time
from typing import Any

import click

from mros_cli.main import master_client, run
from mrosd.errors import MrosError


def _ixm_socket() -> str:
    from mrosd.config import default_ixm_socket

    return default_ixm_socket()


def _ixm_answers(path: str) -> bool:
    if not os.path.exists(path):
        return False
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(1.0)
        try:
            sock.connect(path)
        except OSError:
            return False
    return True


@click.group(name="daemon")
def group() -> None:
    """Check on mrosd, the daemon that runs the master, the IXM registry and rosout.

    \b
    Examples:
      mros daemon status
      mros daemon status --wait 10   # in scripts: wait until the master answers
    """


@group.command()
@click.option("--wait", "wait_s", type=float, default=0.0, metavar="SECONDS", help="Wait this long for the master.")
@click.option("--ixm-socket", default=None, metavar="PATH", help="IXM socket to check (default: as mrosd).")
def status(wait_s: float, ixm_socket: str | None) -> None:
    """Print the master's URI, pid and graph size, and whether the IXM registry answers.

    \b
    Example:
      mros daemon status
    """

    async def main() -> dict[str, Any]:
        deadline = time.monotonic() + wait_s
        async with master_client() as master:
            while True:
                try:
                    pid = await master.call("getPid")
                    break
                except MrosError:
                    if time.monotonic() >= deadline:
                        raise
                    await asyncio.sleep(0.1)
            state = await master.get_system_state()
            nodes = {n for section in state for _t, ns in section for n in ns}
            return {
                "pid": pid,
                "nodes": len(nodes),
                "publications": len(state[0]),
                "subscriptions": len(state[1]),
                "services": len(state[2]),
                "params": len(await master.get_param_names()),
                "uri": master.master_uri,
            }

    info = run(main())
    path = ixm_socket or _ixm_socket()
    click.echo(f"master: running at {info['uri']} (pid {info['pid']})")
    click.echo(
        f"graph: {info['nodes']} nodes, {info['publications']} published topics, "
        f"{info['subscriptions']} subscribed topics, {info['services']} services, {info['params']} parameters"
    )
    click.echo(f"ixm: {'listening' if _ixm_answers(path) else 'not reachable'} at {path}")
    sys.stdout.flush()
