"""Two mrosd daemons with [fleet] on loopback: READY status, a topic across, and `mros fleet status`."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class
from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import Processes, free_port

pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")
String = get_message_class("std_msgs/String")


def config(tmp: Path, robot: str, listen: int, connect: int | None, extra: str) -> Path:
    path = tmp / f"{robot}.toml"
    connect_list = f'"tcp/127.0.0.1:{connect}"' if connect else ""
    path.write_text(
        f'[ixm]\nenabled = false\n[rosout]\nenabled = false\n[fleet]\nenabled = true\nrobot = "{robot}"\n'
        f'listen = ["tcp/127.0.0.1:{listen}"]\nconnect = [{connect_list}]\n{extra}'
    )
    return path


def mros(uri: str, *args: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", uri, *args],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


async def test_two_daemons_and_mros_fleet_status(procs: Processes, tmp_path: Path) -> None:
    z1, z2 = free_port(), free_port()
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    d1 = DaemonRun(
        procs, tmp_path / "a", "--config", str(config(tmp_path, "robot1", z1, None, 'send_topics = ["/chatter"]\n'))
    )
    # robot2 imports robot1's names explicitly: [fleet] receives nothing by default (issue 31)
    d2 = DaemonRun(
        procs, tmp_path / "b", "--config", str(config(tmp_path, "robot2", z2, z1, 'receive_topics = ["/robot1/**"]\n'))
    )
    try:
        assert "fleet robot1" in await asyncio.to_thread(d1.ready)
        assert "fleet robot2" in await asyncio.to_thread(d2.ready)
        async with (
            mrosd.Node("talker", master_uri=d1.uri, argv=[], host="127.0.0.1") as a,
            mrosd.Node("listener", master_uri=d2.uri, argv=[], host="127.0.0.1") as b,
        ):
            pub = await a.advertise("/chatter", String)

            async def talk() -> None:
                while True:
                    pub.publish_nowait(String(data="across daemons"))
                    await asyncio.sleep(0.05)

            talking = asyncio.create_task(talk())
            try:
                async with backports.timeout(20):
                    while True:  # the remote topic appears at robot2's master once announced
                        state = await b.master_call("getSystemState")
                        if any(t == "/robot1/chatter" for t, _ in state[0]):
                            break
                        await asyncio.sleep(0.2)
                sub = await b.subscribe("/robot1/chatter", String)
                assert (await sub.next(timeout=15)).data == "across daemons"
                st = json.loads(await asyncio.to_thread(mros, d1.uri, "fleet", "status", "--json"))
                assert st["robot"] == "robot1" and st["peers"]
                assert st["sent"]["/chatter"]["matched"] and st["sent"]["/chatter"]["messages"] > 0
                text = await asyncio.to_thread(mros, d2.uri, "fleet", "status")
                assert "/robot1/chatter  from robot1  subscribed" in text
            finally:
                talking.cancel()
    finally:
        for d in (d1, d2):
            d.stop()
            d.close()
