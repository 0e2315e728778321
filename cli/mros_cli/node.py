"""``mros node``: list, inspect, ping, kill and clean up nodes, printed as ``rosnode`` prints them.

Node facts come from the master (``getSystemState``, ``lookupNode``) and from each node's slave API
(``getPid``, ``getBusInfo``, ``shutdown``); every call is bounded by the CLI's call timeout.
"""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import AsyncIterator, Sequence
from typing import TYPE_CHECKING, Any

import click

from mros_cli.main import CALL_TIMEOUT, CALLER_ID, error_text, fail, master_client, resolve_name, run, slave_call
from mrosd.errors import MasterError, MasterUnreachableError, MrosError, XmlRpcError

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient
    from mrosd.xmlrpc import XmlRpcClient

#: The free-text connection description roscpp/rospy put in getBusInfo, shown as rosnode shows it.
CONNECTION_PATTERN = re.compile(r"\w+ connection on port (\d+) to \[(.*) on socket (\d+)\]")

#: rosnode ping's timeout for one getPid.
PING_TIMEOUT = 3.0


resolve = resolve_name


def node_names(state: Sequence[Any]) -> list[str]:
    """Every node that appears in a getSystemState answer, sorted."""
    names: set[str] = set()
    for section in state:
        for _name, nodes in section:
            names.update(nodes)
    return sorted(names)


async def _lookup(master: MasterClient, name: str) -> str | None:
    try:
        uri: str = await master.lookup_node(name)
    except MasterUnreachableError:
        raise
    except MasterError:
        return None
    return uri


@contextlib.asynccontextmanager
async def _clients() -> AsyncIterator[tuple[MasterClient, XmlRpcClient]]:
    """A master client and the XML-RPC client it shares with the slave API calls, closed on exit."""
    from mrosd.xmlrpc import XmlRpcClient

    async with XmlRpcClient(timeout=CALL_TIMEOUT) as xmlrpc:
        yield master_client(xmlrpc), xmlrpc


@click.group(name="node")
def group() -> None:
    """List, inspect, ping, kill and clean up nodes (like rosnode).

    \b
    Examples:
      mros node list
      mros node info /talker
      mros node ping /talker -c 3
      mros node machine
      mros node kill /talker
      mros node cleanup -y
    """


@group.command(name="list")
@click.option("-u", "show_uri", is_flag=True, help="Print node XML-RPC URIs instead of names.")
@click.option("-a", "--all", "show_all", is_flag=True, help="Print URI and name of every node.")
@click.argument("namespace", required=False)
def list_(show_uri: bool, show_all: bool, namespace: str | None) -> None:
    """List the nodes registered with the master.

    \b
    Example:
      mros node list
    """

    async def main() -> list[tuple[str, str]]:
        async with master_client() as master:
            names = node_names(await master.get_system_state())
            if namespace:  # as rosnode: the nodes under the namespace, and a node of that very name
                resolved = resolve(namespace)
                prefix = resolved.rstrip("/") + "/"
                names = [n for n in names if n.startswith(prefix) or n == resolved]
            if not (show_uri or show_all):
                return [(n, "") for n in names]
            return [(n, await _lookup(master, n) or "unknown address") for n in names]

    rows = run(main())
    # As rosnode: one line per node in the order of the names, -u included (a URI shared by two names, or
    # 'unknown address', is printed for each), and an empty line when there are no nodes.
    if show_all:
        lines = [f"{uri} \t{name}" for name, uri in rows]
    elif show_uri:
        lines = [uri for _n, uri in rows]
    else:
        lines = [name for name, _u in rows]
    click.echo("\n".join(lines))


def _describe(name: str, state: Sequence[Any], pub_topics: list[Any]) -> str:
    types = {t: ty for t, ty in pub_topics}

    def section(title: str, items: list[str], typed: bool) -> str:
        if not items:
            return f"\n{title}: None\n"
        body = "\n".join(f" * {t} [{types.get(t, 'unknown type')}]" if typed else f" * {t}" for t in items)
        return f"\n{title}: \n{body}\n"

    pubs = sorted(t for t, nodes in state[0] if name in nodes)
    subs = sorted(t for t, nodes in state[1] if name in nodes)
    srvs = sorted(t for t, nodes in state[2] if name in nodes)
    return (
        f"Node [{name}]"
        + section("Publications", pubs, True)
        + section("Subscriptions", subs, True)
        + section("Services", srvs, False)
    )


@group.command()
@click.argument("node")
@click.option("-q", "--quiet", is_flag=True, help="Do not contact the node, only ask the master.")
def info(node: str, quiet: bool) -> None:
    """Print a node's publications, subscriptions, services, pid and connections.

    \b
    Example:
      mros node info /talker
    """
    name = resolve(node)

    async def main() -> tuple[str, str | None, str]:
        async with _clients() as (master, xmlrpc):
            state = await master.get_system_state()
            pub_topics = await master.get_published_topics("/")
            head = _describe(name, state, pub_topics)
            uri = await _lookup(master, name)
            if uri is None or quiet:
                return head, uri, ""
            try:
                pid = await slave_call(xmlrpc, uri, "getPid")
                bus = await slave_call(xmlrpc, uri, "getBusInfo")
            except (XmlRpcError, MasterError) as exc:
                raise MrosError(f"Communication with node[{uri}] failed! ({exc})") from exc
            uris: dict[str, str] = {}
            for section in state[:2]:
                for _t, nodes in section:
                    for n in nodes:
                        if n not in uris:
                            uris[n] = await _lookup(master, n) or ""
            return head, uri, _connections(pid, bus, uris)

    head, uri, conns = run(main())
    click.echo("-" * 80)
    click.echo(head)
    if uri is None:
        click.echo(f"cannot contact [{name}]: unknown node", err=True)
        return
    if not quiet:
        click.echo(f"\ncontacting node {uri} ...")
        click.echo(conns)


def _connections(pid: Any, bus: list[Any], uris: dict[str, str]) -> str:
    by_uri = {u: n for n, u in uris.items() if u}
    text = f"Pid: {pid}\n"
    if bus:
        text += "Connections:\n"
        for entry in bus:
            dest, direction, transport, topic = entry[1], entry[2], entry[3], entry[4]
            connected = entry[5] if len(entry) > 5 else True
            if not connected:
                continue
            peer = f"{by_uri[dest]} ({dest})" if dest in by_uri else dest
            way = {"i": "inbound", "o": "outbound"}.get(direction, "unknown")
            match = CONNECTION_PATTERN.match(entry[6]) if len(entry) > 6 and isinstance(entry[6], str) else None
            if match is not None:
                way += " ({} - {}) [{}]".format(*match.groups())
            text += f" * topic: {topic}\n    * to: {peer}\n    * direction: {way}\n    * transport: {transport}\n"
    return text


@group.command()
@click.argument("node", required=False)
@click.option("-a", "--all", "ping_all", is_flag=True, help="Ping every node.")
@click.option("-c", "count", type=click.IntRange(min=1), help="Number of pings (default: until Ctrl-C).")
def ping(node: str | None, ping_all: bool, count: int | None) -> None:
    """Check that a node's XML-RPC server answers, and how fast (rosnode ping's output).

    As rosnode, the exit code is 0 even when the node is unknown or does not answer: the failure is the
    line on stderr. Scripts that need a verdict can use ``mros node info -q`` or ``mros daemon status``.

    \b
    Examples:
      mros node ping /talker -c 1
      mros node ping --all
    """
    if not node and not ping_all:
        raise click.UsageError("give a NODE or --all")

    async def main() -> None:
        async with _clients() as (master, xmlrpc):
            if ping_all:
                names = node_names(await master.get_system_state())
                click.echo("Will ping the following nodes: \n" + "".join(f" * {n}\n" for n in names))
                dead = [n for n in names if not await _ping(master, xmlrpc, n, 1)]
                if dead:
                    click.echo("ERROR: connection refused to " + ", ".join(dead), err=True)
                return
            name = resolve(node or "")
            click.echo(f"rosnode: node is [{name}]")
            await _ping(master, xmlrpc, name, count)

    run(main())


async def _ping(master: MasterClient, xmlrpc: XmlRpcClient, name: str, count: int | None) -> bool:
    import asyncio

    uri = await _lookup(master, name)
    if uri is None:
        click.echo(f"cannot ping [{name}]: unknown node", err=True)
        return False
    click.echo(f"pinging {name} with a timeout of {PING_TIMEOUT}s")
    done = 0
    while count is None or done < count:
        if done:
            await asyncio.sleep(1.0)
        start = time.perf_counter()
        try:
            await slave_call(xmlrpc, uri, "getPid", timeout=PING_TIMEOUT)
        except (XmlRpcError, MasterError) as exc:
            click.echo(f"connection to [{name}] failed: {exc}", err=True)
            return False
        click.echo(f"xmlrpc reply from {uri}\ttime={(time.perf_counter() - start) * 1000:f}ms")
        done += 1
    return True


async def _addresses(host: str) -> set[str]:
    """Every address ``host`` resolves to (empty when it does not resolve)."""
    import asyncio
    import socket

    try:
        infos = await asyncio.get_running_loop().getaddrinfo(host, 0, proto=socket.IPPROTO_TCP)
    except (OSError, UnicodeError):
        return set()
    return {str(info[4][0]) for info in infos}


@group.command()
@click.argument("host", required=False)
def machine(host: str | None) -> None:
    """List the machines nodes run on, or the nodes on one machine (as rosnode machine).

    A node is on HOST when its XML-RPC URI names HOST or an address HOST resolves to.

    \b
    Examples:
      mros node machine
      mros node machine 192.168.1.20
    """
    import urllib.parse

    async def main() -> list[str]:
        async with master_client() as master:
            names = node_names(await master.get_system_state())
            hosts: dict[str, str] = {}
            for name in names:
                uri = await _lookup(master, name)
                hostname = urllib.parse.urlsplit(uri).hostname if uri else None
                if hostname:
                    hosts[name] = hostname
            if host is None:
                return sorted(set(hosts.values()))
            wanted = await _addresses(host)
            if not wanted:
                fail(f"cannot resolve machine name [{host}] to address")
            known: dict[str, bool] = {}
            found = []
            for name, hostname in hosts.items():
                if hostname not in known:
                    known[hostname] = hostname == host or bool(wanted & await _addresses(hostname))
                if known[hostname]:
                    found.append(name)
            return sorted(found)

    click.echo("\n".join(run(main())))


@group.command()
@click.argument("nodes", nargs=-1)
@click.option("-a", "--all", "kill_all", is_flag=True, help="Kill every node.")
def kill(nodes: tuple[str, ...], kill_all: bool) -> None:
    """Ask nodes to shut down (slave API ``shutdown``).

    \b
    Example:
      mros node kill /talker
    """
    if not nodes and not kill_all:
        raise click.UsageError("give NODE names or --all")

    async def main() -> list[str]:
        failed: list[str] = []
        async with _clients() as (master, xmlrpc):
            known = node_names(await master.get_system_state())
            names = known if kill_all else [resolve(n) for n in nodes]
            unknown = [n for n in names if n not in known]
            if unknown:
                fail("Unknown node(s):\n" + "\n".join(f" * {n}" for n in unknown))  # rosnode's lines
            if len(names) > 1:
                click.echo("killing:\n" + "\n".join(f" * {n}" for n in names))
            elif names:
                click.echo(f"killing {names[0]}")
            for name in names:
                uri = await _lookup(master, name)
                if uri is None:
                    failed.append(name)
                    continue
                # A node may tear down while answering, so a broken reply still counts as killed (as rosnode).
                with contextlib.suppress(XmlRpcError, MasterError):
                    await slave_call(xmlrpc, uri, "shutdown", "user request")
        return failed

    failed = run(main())
    if failed:
        fail("Failed to kill: " + ", ".join(failed))
    click.echo("killed")


@group.command()
@click.option("-y", "--yes", is_flag=True, help="Do not ask for confirmation.")
def cleanup(yes: bool) -> None:
    """Purge nodes that no longer answer from the master's registrations.

    \b
    Example:
      mros node cleanup -y
    """

    async def dead_nodes(master: MasterClient, xmlrpc: XmlRpcClient) -> tuple[Sequence[Any], list[tuple[str, str]]]:
        state = await master.get_system_state()
        dead: list[tuple[str, str]] = []
        for name in node_names(state):
            uri = await _lookup(master, name)
            if uri is None:
                continue
            try:
                await slave_call(xmlrpc, uri, "getPid", timeout=PING_TIMEOUT)
            except (XmlRpcError, MasterError):
                dead.append((name, uri))
        return state, dead

    async def purge(
        master: MasterClient, xmlrpc: XmlRpcClient, state: Sequence[Any], dead: list[tuple[str, str]]
    ) -> None:
        from mrosd.master.client import MasterClient as client_class

        for name, uri in dead:
            click.echo(f"Unregistering {name}")
            for method, section, extra in (
                ("unregisterPublisher", state[0], True),
                ("unregisterSubscriber", state[1], True),
                ("unregisterService", state[2], False),
            ):
                for item, nodes in section:
                    if name not in nodes:
                        continue
                    api = uri if extra else await _service_uri(master, item)
                    # Unregister as the dead node itself (its caller id), like rosnode cleanup.
                    as_node = client_class(master.master_uri, name, xmlrpc, timeout=CALL_TIMEOUT)
                    try:
                        await as_node.call(method, item, api)
                    except MasterError as exc:
                        click.echo(error_text(f"{method} {item} for {name}: {exc}"), err=True)

    async def main() -> None:
        async with _clients() as (master, xmlrpc):
            state, dead = await dead_nodes(master, xmlrpc)
            if not dead:
                return
            if not yes:
                click.echo("Unable to contact the following nodes:")
                click.echo("\n".join(f" * {n}" for n, _u in dead))
                click.echo("Cleanup will purge all information about these nodes from the master.")
                if not click.confirm("Continue?", default=False):
                    click.echo("aborting")
                    return
            await purge(master, xmlrpc, state, dead)
            click.echo("done")

    run(main())


async def _service_uri(master: MasterClient, service: str) -> str:
    try:
        uri: str = await master.lookup_service(service)
    except MasterError:
        return ""
    return uri


__all__ = ["CALLER_ID", "group", "node_names"]
