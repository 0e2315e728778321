"""`mros topic echo` decodes a type that exists nowhere on this machine, from the publisher's definition."""

from __future__ import annotations

import subprocess
import sys

from tests.rosenv import Processes, free_port, wait_for_xmlrpc

PUBLISHER = """
import asyncio, sys
import mrosd
from mrosd.msg import load_type

DEFINITION = "float64 value\\nstring label\\nuint8[] raw\\n"

async def main():
    cls = load_type("nowhere_pkg/Reading", DEFINITION)
    async with mrosd.Node("custom_pub", master_uri=sys.argv[1], argv=[]) as node:
        pub = await node.advertise("/reading", cls, latch=True)
        await pub.publish(cls(value=2.5, label="left wheel", raw=b"\\x01\\x02"))
        print("up", flush=True)
        await asyncio.sleep(60)

asyncio.run(main())
"""


def test_echo_decodes_a_type_known_only_to_the_publisher(procs: Processes) -> None:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    procs.our_python(["-m", "mrosd.daemon", "--master-only", "--port", str(port)], stderr=subprocess.DEVNULL)
    wait_for_xmlrpc(uri)
    pub = procs.our_python(["-c", PUBLISHER, uri])
    assert pub.stdout is not None
    assert pub.stdout.readline().strip() == b"up"
    out = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", uri, "topic", "echo", "-n", "1", "/reading"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout == 'value: 2.5\nlabel: "left wheel"\nraw: [1, 2]\n---\n'
    typed = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", uri, "topic", "type", "/reading"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert typed.stdout == "nowhere_pkg/Reading\n"
