"""``mros fleet``: what the daemon's fleet part (mrosd/fleet, docs/fleet.md) links, sends and receives.

The fleet node answers ``/mrosd_fleet/status`` (std_srvs/Trigger) with its status as JSON; this command asks
it through the master like any service client, so it works from any host that reaches the master.
"""

from __future__ import annotations

import json
from typing import Any

import click

from mros_cli.main import anonymous, fail, master_uri, run
from mrosd.errors import MrosError

#: The fleet node's status service (FleetBridge's ``~status`` of node ``mrosd_fleet``).
STATUS_SERVICE = "/mrosd_fleet/status"


@click.group(name="fleet")
def group() -> None:
    """Inspect the fleet link of this robot's mrosd (topics and services shared over Zenoh).

    \b
    Examples:
      mros fleet status
      mros fleet status --json
    """


async def fetch_status(uri: str, timeout: float = 5.0) -> dict[str, Any]:
    """The fleet node's status.

    Raises:
        MrosError: the fleet part is not running (service unknown) or does not answer.
    """
    from mrosd.msg import get_service_class
    from mrosd.tcpros.node import Node

    trigger = get_service_class("std_srvs/Trigger")
    async with Node(anonymous("fleet"), master_uri=uri, argv=[], rosout=False, logger_services=False) as node:
        resp = await node.service_proxy(STATUS_SERVICE, trigger).call(trigger._request_class(), timeout=timeout)
    status: dict[str, Any] = json.loads(resp.message)
    return status


def format_status(st: dict[str, Any]) -> str:
    """The human-readable report: peers, then one line per sent and received topic and service."""
    lines = [
        f"robot:   {st['robot']} ({st['mode']}, zenoh id {st['zid']})",
        f"peers:   {', '.join(st['peers']) or 'none'}",
        f"remote items heard: {st['remote_items']}  bad announcements: {st['bad_announcements']}",
        "",
        "sent topics:",
    ]
    for topic, t in sorted(st["sent"].items()):
        wanted = "asked for" if t["matched"] else "nobody asked"
        lines.append(
            f"  {topic}  {wanted}  {t['messages']} msgs {t['bytes']} B  {t['rate_hz']:.1f} Hz  "
            f"dropped {t['dropped']}  rate-limited {t['rate_limited']}{'  latched' if t['latched'] else ''}"
        )
    lines.append("received topics:")
    for topic, t in sorted(st["received"].items()):
        state = "subscribed" if t["subscribed"] else "idle (no local subscriber)"
        lines.append(
            f"  {topic}  from {t['robot']}  {state}  {t['messages']} msgs {t['bytes']} B  "
            f"{t['rate_hz']:.1f} Hz  dropped {t['dropped']}{'  latched' if t['latched'] else ''}"
        )
    lines.append("services sent:")
    lines += [f"  {n}  {s['calls']} calls  {s['errors']} errors" for n, s in sorted(st["services_sent"].items())]
    lines.append("services received:")
    lines += [f"  {n}  {s['calls']} calls  {s['errors']} errors" for n, s in sorted(st["services_received"].items())]
    return "\n".join(lines)


@group.command(name="status")
@click.option("--json", "as_json", is_flag=True, help="Print the status as JSON.")
def status(as_json: bool) -> None:
    """Peers, links, and per-topic messages, rates and drops of the fleet part."""
    try:
        st = run(fetch_status(master_uri()))
    except MrosError as exc:
        fail(f"the fleet part does not answer ({exc}); is [fleet] enabled in mrosd.toml?")
    click.echo(json.dumps(st, indent=2, sort_keys=True) if as_json else format_status(st))
