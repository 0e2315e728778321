"""The daemon's web part: on by default, its URL in the status line, degraded (not dead) when its port is taken."""

from __future__ import annotations

import asyncio
import json
import re
import socket
from pathlib import Path

import aiohttp
import pytest

from mrosd.config import parse_config
from mrosd.errors import ConfigError
from tests.integration.daemon.daemonproc import DaemonRun, daemon_env
from tests.rosenv import Processes


def foxglove_url(status: str) -> str:
    match = re.search(r"foxglove (ws://\S+/)", status)
    assert match, status
    return match.group(1)


async def server_info(url: str) -> dict[str, object]:
    async with (
        aiohttp.ClientSession() as http,
        http.ws_connect(url, protocols=["foxglove.websocket.v1"]) as ws,
    ):
        msg = await ws.receive(timeout=10)
        data: dict[str, object] = json.loads(msg.data)
        return data


def test_the_daemon_serves_foxglove_on_loopback_by_default(procs: Processes, tmp_path: Path) -> None:
    run = DaemonRun(procs, tmp_path)
    try:
        status = run.ready()
        assert status.startswith("running:"), status
        url = foxglove_url(status)
        assert url.startswith("ws://127.0.0.1:")
        assert "rosbridge ws://127.0.0.1:" in status
        info = asyncio.run(server_info(url))
        assert info["op"] == "serverInfo"
        code, _ = run.stop()
        assert code == 0, run.stderr()
    finally:
        run.close()


def test_a_taken_web_port_leaves_the_daemon_degraded_not_dead(procs: Processes, tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        env = daemon_env(tmp_path, MROSD_WEB_PORT=str(busy.getsockname()[1]))
        run = DaemonRun(procs, tmp_path, env=env)
        try:
            status = run.ready()
            assert status.startswith("degraded:"), status
            assert "web failed" in status
            code, _ = run.stop()
            assert code == 0
        finally:
            run.close()


def test_the_daemon_serves_every_address_of_mrosd_web_host(procs: Processes, tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET6) as probe:
        try:
            probe.bind(("::1", 0))
        except OSError:
            pytest.skip("this machine has no IPv6 loopback (::1 cannot be bound)")
    run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, MROSD_WEB_HOST="127.0.0.1,::1"))
    try:
        status = run.ready()
        match = re.search(r"foxglove (ws://\S+/) (ws://\S+/), rosbridge (ws://\S+/) (ws://\S+/)", status)
        assert match, status
        v4, v6 = match.group(1), match.group(2)
        assert v4.startswith("ws://127.0.0.1:") and v6 == v4.replace("127.0.0.1", "[::1]"), status
        assert match.group(4).startswith("ws://[::1]:"), status
        for url in (v4, v6):
            assert asyncio.run(server_info(url))["op"] == "serverInfo"
        assert run.stop()[0] == 0, run.stderr()
    finally:
        run.close()


def test_web_off_loopback_needs_a_token() -> None:
    with pytest.raises(ConfigError, match=r"web\.token"):
        parse_config('[web]\nhost = "0.0.0.0"\n', "mrosd.toml")
    cfg = parse_config('[web]\nhost = "0.0.0.0"\ntoken = "s3cret"\ntopics = ["/camera/*"]\n', "mrosd.toml")
    assert cfg.web.topics == ["/camera/*"]
    assert not parse_config("[web]\nenabled = false\n").web.enabled
