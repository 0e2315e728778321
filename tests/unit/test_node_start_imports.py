"""A node (every ``mros topic pub``, every embedded node) imports only the node stack: not the master's server
side, not the shared-memory endpoints, the IXM client or the daemon's configuration, which it loads when a
peer offers shared memory. Each of those cost start-up time before the first registration."""

from __future__ import annotations

import subprocess
import sys

SERVER_SIDE = [
    "mrosd.master.server",
    "mrosd.master.api",
    "mrosd.master.registry",
    "mrosd.shm.publisher",
    "mrosd.shm.subscriber",
    "mrosd.ixm.client",
    "mrosd.config",
]


def test_starting_a_node_loads_no_master_server_and_no_shared_memory_endpoint() -> None:
    probe = f"import sys, mrosd.tcpros.node\nprint(' '.join(m for m in {SERVER_SIDE!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == []


def test_the_lazy_packages_still_export_their_names() -> None:
    import mrosd.master
    import mrosd.shm

    for package in (mrosd.master, mrosd.shm):
        for name in package.__all__:
            assert getattr(package, name) is not None, (package.__name__, name)


def test_a_node_imports_no_aiohttp() -> None:
    """aiohttp's import alone took ~240 ms of a node's start-up (its connector builds SSL contexts): a node's
    XML-RPC (client and slave API) runs on the project's own HTTP/1.1 framing instead."""
    probe = "import sys, mrosd.tcpros.node, mrosd.xmlrpc.client, mrosd.xmlrpc.server\nprint('aiohttp' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == ["False"]
