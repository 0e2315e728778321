"""The daemon as shipped (web part on, tf2_web_republisher on) adds nothing to the graph until a web client
comes: ros_comm's test_rosmaster counts every service a fresh master holds (all but ``/rosout/*`` and loggers)
and every publisher a type probe touches, so the web part's rosapi services, its ``/republish_tfs`` and its type
probes wait for the first client (issue 31, case 10). Then they join the graph, before that client's first op.
"""

from __future__ import annotations

import asyncio
import json
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path

import aiohttp
import pytest

from tests.rosenv import Processes
from tests.web.webdaemon import WebDaemon


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[WebDaemon]:
    procs = Processes(tmp_path)
    run = WebDaemon(procs, tmp_path)
    yield run
    run.close()
    procs.close()


def _services(uri: str) -> list[str]:
    with xmlrpc.client.ServerProxy(uri) as master:
        _, _, (_, _, services) = master.getSystemState("/probe")
    return [
        name
        for name, _ in services
        if not name.startswith("/rosout/") and not name.endswith(("/get_loggers", "/set_logger_level"))
    ]


def test_no_service_of_the_web_part_is_in_the_graph_until_a_client_comes(daemon: WebDaemon) -> None:
    assert _services(daemon.uri) == []

    async def first_client() -> list[str]:
        async with aiohttp.ClientSession() as http, http.ws_connect(daemon.rosbridge_url) as ws:
            # the client's very first op already finds the services in the graph
            await ws.send_str(json.dumps({"op": "call_service", "service": "/republish_tfs", "id": "r", "args": {}}))
            reply = json.loads((await ws.receive(timeout=20)).data)
            return [reply["op"], reply["id"]]

    assert asyncio.run(first_client()) == ["service_response", "r"]
    services = _services(daemon.uri)
    assert "/republish_tfs" in services and "/rosapi/topics" in services, services
