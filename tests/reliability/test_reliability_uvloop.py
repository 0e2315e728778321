"""mrosd nodes on uvloop, the loop the daemon (and so its built-in rosout aggregator) runs on by default."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from tests.reliability.relnodes import node_env, start_master
from tests.rosenv import Processes

SELF_TALK = textwrap.dedent(
    """
    import asyncio, uvloop, mrosd
    from mrosd import backports
    from mrosd.msg import get_message_class
    String = get_message_class("std_msgs/String")
    async def main():
        async with mrosd.Node("uv", host="127.0.0.1", argv=[]) as node:
            pub = await node.advertise("/uv", String)
            sub = await node.subscribe("/uv", String)
            async def send():
                while True:
                    await pub.publish(String(data="hi"))
                    await asyncio.sleep(0.05)
            sender = asyncio.create_task(send())
            print((await backports.wait_for(sub.__anext__(), 2)).data, flush=True)
            sender.cancel()
    uvloop.install()
    asyncio.run(main())
    """
)


def test_a_node_on_uvloop_receives_its_own_topic(procs: Processes, tmp_path: Path) -> None:
    _, uri = start_master(procs)
    done = subprocess.run(
        [sys.executable, "-c", SELF_TALK], env=node_env(uri, tmp_path), capture_output=True, timeout=30, check=False
    )
    assert done.stdout.decode().strip() == "hi", done.stderr.decode()[-2000:]


def test_the_master_on_its_default_uvloop_answers_and_registers(procs: Processes) -> None:
    """`python -m mrosd.master` (and the daemon) install uvloop by default: the master must work there."""
    import xmlrpc.client

    _, uri = start_master(procs)  # no --no-uvloop
    with xmlrpc.client.ServerProxy(uri) as master:
        code, _, _ = master.registerPublisher("/probe", "/uv", "std_msgs/String", "http://127.0.0.1:1/")
        assert code == 1
        assert master.getSystemState("/probe")[2][0] == [["/uv", ["/probe"]]]
