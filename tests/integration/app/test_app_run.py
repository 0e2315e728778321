"""``mrosd.run``: SIGINT/SIGTERM end an embedded node quietly, with status 0, unregistered from the master.

The application is a real subprocess (a signal must reach a real process) against mrosd's master in the
test's loop; the examples in ``examples/`` are run as users run them.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time

import pytest

from mrosd import backports
from mrosd.master import Master
from tests.rosenv import PROJECT_ROOT, Processes

#: An app that leaves a second node open on purpose (never closed by the app): mrosd.run closes it.
APP = """
import asyncio, sys, mrosd
from mrosd.msg import get_message_class
String = get_message_class("std_msgs/String")

async def main():
    stray = mrosd.Node("stray", argv=[])
    await stray.start()
    await stray.advertise("/stray_topic", String)
    async with mrosd.Node("app", argv=[]) as node:
        await node.advertise("/app_topic", String)
        await node.subscribe("/app_in", String)
        print("up", flush=True)
        await node.spin()
    print("spin returned", flush=True)

mrosd.run(main)
print("after run", flush=True)
"""


def _env(master_uri: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    root = str(PROJECT_ROOT)
    env.update(
        ROS_MASTER_URI=master_uri,
        ROS_HOSTNAME="127.0.0.1",
        PYTHONPATH=os.pathsep.join([root, os.path.join(root, "cli"), env.get("PYTHONPATH", "")]),
    )
    return env


async def _nodes(master: Master) -> set[str]:
    _, _, (pubs, subs, srvs) = master.api.get_system_state("/test")
    return {n for _, nodes in [*pubs, *subs, *srvs] for n in nodes}


async def _run_until_up(procs: Processes, argv: list[str], master: Master, wanted: set[str]) -> subprocess.Popen[bytes]:
    proc = procs.start(argv, _env(master.uri))
    deadline = time.monotonic() + 20
    while not wanted <= await _nodes(master):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            _, err = proc.communicate()
            pytest.fail(f"the app did not register {wanted}: {err.decode()}")
        await asyncio.sleep(0.02)
    return proc


async def _stop(
    proc: subprocess.Popen[bytes], master: Master, signum: signal.Signals, names: set[str], *, repeat: int = 1
) -> float:
    """Send ``signum`` (``repeat`` times at once); return the seconds until none of ``names`` is in the
    master's lists."""
    start = time.monotonic()
    for _ in range(repeat):
        proc.send_signal(signum)
    while names & await _nodes(master):
        if time.monotonic() - start > 5:
            break
        await asyncio.sleep(0.01)
    return time.monotonic() - start


@pytest.mark.parametrize("repeat", [1, 3], ids=["once", "thrice"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
async def test_a_signal_ends_the_app_quietly_with_status_0_and_unregistered(
    procs: Processes, signum: signal.Signals, repeat: int
) -> None:
    """A repeated signal (Ctrl-C pressed again while closing) still lets every node unregister."""
    async with Master(host="127.0.0.1", port=0) as master:
        proc = await _run_until_up(procs, [sys.executable, "-c", APP], master, {"/app", "/stray"})
        assert proc.stdout is not None
        assert await asyncio.to_thread(proc.stdout.readline) == b"up\n"  # main is in spin(), not starting
        try:
            gone_after = await _stop(proc, master, signum, {"/app", "/stray"}, repeat=repeat)
            out, err = await asyncio.to_thread(proc.communicate, timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert proc.returncode == 0, err.decode()
        assert err.decode() == ""  # no traceback, no KeyboardInterrupt, no warning
        assert out.decode().split("\n") == ["after run", ""]  # cancelled: spin() did not return
        assert gone_after < 1.0


async def test_spin_returns_when_the_node_is_told_to_shut_down(procs: Processes) -> None:
    async with Master(host="127.0.0.1", port=0) as master:
        proc = await _run_until_up(procs, [sys.executable, "-c", APP], master, {"/app"})
        try:
            uri = master.api.registry.lookup_node("/app")
            from mrosd.xmlrpc import XmlRpcClient

            client = XmlRpcClient(timeout=5)
            try:
                await client.call(uri, "shutdown", "/test", "rosnode kill")  # what `rosnode kill /app` sends
            finally:
                await client.aclose()
            out, err = await asyncio.to_thread(proc.communicate, timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert proc.returncode == 0, err.decode()
        assert out.decode().split("\n") == ["up", "spin returned", "after run", ""]
        assert not {"/app", "/stray"} & await _nodes(master)


@pytest.mark.parametrize("example", ["talker.py", "listener.py"])
async def test_the_examples_stop_cleanly_on_ctrl_c(procs: Processes, example: str) -> None:
    async with Master(host="127.0.0.1", port=0) as master:
        name = "/" + example.removesuffix(".py")
        path = str(PROJECT_ROOT / "examples" / example)
        proc = await _run_until_up(procs, [sys.executable, path], master, {name})
        try:
            gone_after = await _stop(proc, master, signal.SIGINT, {name})
            _, err = await asyncio.to_thread(proc.communicate, timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert (proc.returncode, err.decode()) == (0, "")
        assert gone_after < 1.0


async def test_the_example_talker_prints_what_it_publishes_as_rospy_s_does(procs: Processes) -> None:
    """rospy's talker prints ``[INFO] [<seconds>]: hello world ...`` for each message it publishes."""
    import re

    async with Master(host="127.0.0.1", port=0) as master:
        proc = await _run_until_up(procs, [sys.executable, str(PROJECT_ROOT / "examples" / "talker.py")], master, set())
        try:
            assert proc.stdout is not None
            line = await backports.wait_for(asyncio.to_thread(proc.stdout.readline), timeout=10)
            proc.send_signal(signal.SIGINT)
            _, err = await asyncio.to_thread(proc.communicate, timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert re.fullmatch(rb"\[INFO\] \[\d+\.\d+\]: hello world 0\n", line), line
    assert (proc.returncode, err.decode()) == (0, "")
