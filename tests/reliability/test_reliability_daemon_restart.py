"""The whole daemon (master + IXM + rosout) SIGKILLed and restarted: nodes re-register, IXM clients re-open,
no segment of the crashed run outlives its holders. And the master's allow-list on loopback (no root needed)."""

from __future__ import annotations

import os
import subprocess
import sys
import xmlrpc.client
from pathlib import Path

import pytest

from mrosd.errors import IxmError
from mrosd.ixm.client import IxmClient
from mrosd.ixm.server import segment_prefix
from mrosd.master import Master
from tests.integration.ixm.conftest import own_segments
from tests.reliability.relnodes import TALKER, kill9, node_env, topic_nodes, wait_until
from tests.rosenv import Processes, free_port, iter_lines_until, wait_for_xmlrpc


def start_daemon(procs: Processes, port: int, env: dict[str, str]) -> subprocess.Popen[bytes]:
    proc = procs.start(
        [sys.executable, "-m", "mrosd.daemon", "--port", str(port), "--log-level", "error"],
        env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc(f"http://127.0.0.1:{port}/")
    wait_until(lambda: os.path.exists(env["MROSD_IXM_SOCKET"]), 10.0, "the IXM socket exists")
    return proc


def test_the_daemon_killed_with_sigkill_and_restarted_gets_nodes_and_ixm_clients_back_without_stale_segments(
    procs: Processes, tmp_path: Path
) -> None:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    sock = str(tmp_path / "ixm.sock")
    env = node_env(uri, tmp_path) | {"MROSD_IXM_SOCKET": sock, "MROSD_MASTER_HOST": "127.0.0.1"}
    daemon = start_daemon(procs, port, env)
    talker = procs.our_python(["-c", TALKER, "/chatter", "20", "talker"], env)
    assert next(iter_lines_until(talker, 1, 20.0)) == "ready"
    client = IxmClient(sock, name="holder")
    client.open("/state", "int64", mode="rw").write(41)
    assert own_segments(sock), "the key's segment is held (by the daemon and the client)"
    assert not {n for n in os.listdir("/dev/shm") if n.startswith(segment_prefix(sock))}, "a segment has a name"

    kill9(daemon)
    with pytest.raises(IxmError):
        client.open("/again", "int64", mode="w")
    client.close()
    # the crashed run's segments were nameless memfds: gone with their last holder, nothing to clean up
    wait_until(lambda: not own_segments(sock), 5.0, "no process holds a segment of the crashed run")

    start_daemon(procs, port, env)
    wait_until(lambda: topic_nodes(uri, "/chatter")[0] == {"/talker"}, 15.0, "the talker re-registered")
    with IxmClient(sock, name="back") as again:
        key = again.open("/state", "int64", mode="rw")
        key.write(42)
        assert key.read() == 42
        key.close()


async def test_the_master_allow_list_refuses_loopback_when_only_another_network_is_listed() -> None:
    async with Master("127.0.0.1", 0, allow=["10.99.0.0/16"]) as master:
        uri = f"http://127.0.0.1:{master.port}/"
        with xmlrpc.client.ServerProxy(uri) as proxy, pytest.raises(xmlrpc.client.ProtocolError) as refused:
            await _in_thread(proxy.getPid, "/intruder")
        assert refused.value.errcode == 403
    async with Master("127.0.0.1", 0, allow=["127.0.0.0/8"]) as master:
        with xmlrpc.client.ServerProxy(f"http://127.0.0.1:{master.port}/") as proxy:
            code, _, pid = await _in_thread(proxy.getPid, "/friend")
        assert code == 1 and pid == os.getpid()


async def _in_thread(fn: object, *args: object) -> object:
    import asyncio

    return await asyncio.to_thread(fn, *args)  # type: ignore[arg-type]
