"""``mros daemon``: is mrosd (or any ROS master) up, and what does it hold.

``status`` asks the master for its pid, URI and graph size, reads which parts the daemon runs and where
(its status file, ``mrosd.runstatus``: web page and WebSocket URLs, rosout, IXM, fleet, and each part that
failed to start with the reason), and checks whether the IXM registry's socket accepts connections. Exit
code 0 when the master answers and every part started, 1 otherwise (no master, or a part failed), so
scripts can wait on it. A master that is not mrosd (rosmaster, another host) has no status file: then only
the master's lines are printed.
"""

from __future__ import annotations

import asyncio
import os
import socket
import sys
import time
from typing import TYPE_CHECKING, Any

import click

from mros_cli.main import master_client, run
from mrosd.errors import MrosError

if TYPE_CHECKING:
    from mrosd.runstatus import DaemonStatus


def _ixm_socket() -> str:
    from mrosd.ixm.rundir import find_ixm_socket

    return find_ixm_socket()


def daemon_status(uri: str) -> DaemonStatus | None:
    """The running daemon's status file for the master at ``uri`` (None: no mrosd of this host serves it)."""
    from mrosd.ixm.rundir import client_run_dirs
    from mrosd.runstatus import find_status

    return find_status(uri, client_run_dirs())


def part_lines(st: DaemonStatus) -> list[str]:
    """One line per part of the daemon, failed ones with their reason."""
    lines = []
    if st.web is not None:
        urls = [f"foxglove {' '.join(st.web.foxglove)}"]
        if st.web.rosbridge:
            urls.append(f"rosbridge {' '.join(st.web.rosbridge)}")
        token = " (token required)" if st.web.token_required else ""
        lines.append(f"web: page {st.web.page}{token}, {', '.join(urls)}")
        for drops in st.web.drops:  # a client whose link is slower than its topics
            counts = ", ".join(f"{topic} {n}" for topic, n in drops.dropped.items())
            lines.append(f"web: dropped for {drops.client}: {counts}")
        for enc in st.web.encoders:  # T/compressed made for browser clients
            ms = f", {enc.encode_ms:.1f} ms per frame" if enc.encode_ms is not None else ""
            lines.append(f"web: {enc.topic}: {enc.encoded} encoded, {enc.dropped} dropped, {enc.refused} refused{ms}")
    if st.rosout:
        lines.append("rosout: running (/rosout -> /rosout_agg)")
    if st.ixm_bridges:
        lines.append(f"ixm bridges: {st.ixm_bridges}")
    if st.fleet is not None:
        lines.append(f"fleet: robot {st.fleet}")
    lines += [f"{name}: failed to start: {why}" for name, why in st.failed.items()]
    return lines


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
    """Print the master's URI, pid and graph size, the daemon's parts and addresses, and whether the IXM
    registry answers. Exits 1 when a part failed to start.

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
    st = daemon_status(info["uri"])
    if st is not None and st.pid != info["pid"]:
        st = None  # the file of another process on that port number (a master elsewhere answered)
    if st is not None:
        click.echo(f"mrosd: {st.version}, {st.state}")
        for line in part_lines(st):
            click.echo(line)
    click.echo(f"ixm: {'listening' if _ixm_answers(path) else 'not reachable'} at {path}")
    sys.stdout.flush()
    if st is not None and st.failed:
        sys.exit(1)
