"""The ``[ixm.rules.bridges]`` table is run by the daemon: a shared-memory write reaches a TCPROS subscriber."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import pytest

from mrosd import Node, backports
from mrosd.ixm import AsyncIxmClient
from mrosd.msg import get_message_class
from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import Processes

CONFIG = """
[rosout]
enabled = false
[ixm.rules.bridges."/arm/value"]
topic = "/arm_value"
type = "std_msgs/Float64"
"""


@pytest.fixture
def daemon(procs: Processes, tmp_path: Path) -> Iterator[DaemonRun]:
    config = tmp_path / "mrosd.toml"
    config.write_text(CONFIG)
    run = DaemonRun(procs, tmp_path, "--config", str(config))
    yield run
    run.close()


async def test_the_daemon_runs_the_configured_bridges(daemon: DaemonRun) -> None:
    status = await asyncio.to_thread(daemon.ready)
    assert status.startswith("running:") and "1 ixm bridge(s)" in status, status
    Float64 = get_message_class("std_msgs/Float64")
    async with Node("bridge_probe", master_uri=daemon.uri, host="127.0.0.1", argv=[]) as node:
        sub = await node.subscribe("/arm_value", Float64)
        async with AsyncIxmClient(daemon.ixm_socket) as ixm:
            key = await ixm.open("/arm/value", "std_msgs/Float64", mode="w")
            async with backports.timeout(20):  # the TCPROS connection may still be forming: write until one arrives
                value = 1.0
                while True:
                    key.write(Float64(data=value))
                    try:
                        async with backports.timeout(0.5):
                            got = await sub.__anext__()
                        break
                    except TimeoutError:
                        value += 1.0
            assert got.data >= 1.0
            key.write(Float64(data=42.5))
            async with backports.timeout(10):
                while (await sub.__anext__()).data != 42.5:
                    pass
    code, _ = daemon.stop()
    assert code == 0, daemon.stderr()
