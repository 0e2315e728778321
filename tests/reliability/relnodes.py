"""Node programs for the fault and load tests, run as real processes under the project's python."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

from tests.rosenv import Processes, free_port, wait_for_xmlrpc

#: Publishes std_msgs/String "<n>" on argv[1] at argv[2] Hz forever (watchdog fast so re-registration is quick).
TALKER = """
import asyncio, sys, mrosd
from mrosd.msg import get_message_class
String = get_message_class("std_msgs/String")
async def main():
    async with mrosd.Node(sys.argv[3], watchdog_interval=0.2) as node:
        pub = await node.advertise(sys.argv[1], String)
        print("ready", flush=True)
        n = 0
        while True:
            await pub.publish(String(data=str(n)))
            n += 1
            await asyncio.sleep(1 / float(sys.argv[2]))
asyncio.run(main())
"""

#: Prints the data of every std_msgs/String received on argv[1], one line each.
LISTENER = """
import asyncio, sys, mrosd
from mrosd.msg import get_message_class
String = get_message_class("std_msgs/String")
async def main():
    async with mrosd.Node(sys.argv[2], watchdog_interval=0.2) as node:
        sub = await node.subscribe(sys.argv[1], String)
        async for msg in sub:
            print(msg.data, flush=True)
asyncio.run(main())
"""


def node_env(master_uri: str, tmp: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(ROS_MASTER_URI=master_uri, ROS_HOSTNAME="127.0.0.1", ROS_HOME=str(tmp / "ros_home"))
    return env


def start_master(procs: Processes, port: int | None = None, *extra: str) -> tuple[subprocess.Popen[bytes], str]:
    port = port or free_port()
    uri = f"http://127.0.0.1:{port}/"
    proc = procs.our_python(
        ["-m", "mrosd.master", "--host", "127.0.0.1", "--port", str(port), *extra],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc(uri)
    return proc, uri


def kill9(proc: subprocess.Popen[bytes]) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(10)


def system_state(master_uri: str) -> Any:
    with xmlrpc.client.ServerProxy(master_uri) as proxy:
        code, msg, state = proxy.getSystemState("/test")
    assert code == 1, msg
    return state


def wait_until(predicate: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"not within {timeout} s: {what}")


def topic_nodes(master_uri: str, topic: str) -> tuple[set[str], set[str]]:
    pubs, subs, _ = system_state(master_uri)
    return (
        {n for t, ns in pubs if t == topic for n in ns},
        {n for t, ns in subs if t == topic for n in ns},
    )


def dumps(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True)
