"""Issue 31 cases 5 (nesting) and 6 against a real daemon: deeply nested JSON on both protocols is refused
like any malformed op (a status, at most a few rate-limited log lines, never a traceback), and rosbridge's
``fragment_size`` cannot make the daemon build megabytes of fragments at once; the master answers getPid
within 1 s throughout and the daemon's RSS grows < 256 MiB.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Iterator
from pathlib import Path

import aiohttp
import pytest

from mrosd import backports
from tests.rosenv import Processes
from tests.web.webdaemon import MiB, Watch, WebDaemon


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[WebDaemon]:
    procs = Processes(tmp_path)
    run = WebDaemon(procs, tmp_path)
    yield run
    run.close()
    procs.close()


def nested(depth: int) -> str:
    return "[" * depth + "]" * depth


#: One nested value in every place a client's JSON may hold any value, on each protocol.
ROSBRIDGE_OPS = [
    '{"op":"publish","topic":"/x","msg":{"a":%s}}',
    '{"op":"call_service","service":"/rosapi/set_param","args":%s}',
    '{"op":"service_response","id":"1","values":%s}',
    '{"op":%s}',
    "%s",
]
FOXGLOVE_OPS = [
    '{"op":"setParameters","parameters":[{"name":"/x","value":%s}]}',
    '{"op":%s}',
    "%s",
]


def test_deeply_nested_json_is_refused_on_both_protocols_without_a_traceback(daemon: WebDaemon) -> None:
    async def main() -> None:
        async with aiohttp.ClientSession() as http:
            for depth in (200, 2_000, 100_000):
                for template in ROSBRIDGE_OPS:
                    ws = await http.ws_connect(daemon.rosbridge_url)
                    await ws.send_str(template.replace("%s", nested(depth)))
                    msg = await ws.receive(timeout=10)
                    if msg.type == aiohttp.WSMsgType.TEXT:
                        reply = json.loads(msg.data)
                        assert reply["op"] in ("status", "service_response"), reply
                        if reply["op"] == "service_response":
                            assert reply["result"] is False, reply
                    else:
                        assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED), msg
                    await ws.close()
                for template in FOXGLOVE_OPS:
                    ws = await http.ws_connect(daemon.foxglove_url, protocols=["foxglove.websocket.v1"])
                    await ws.send_str(template.replace("%s", nested(depth)))
                    while True:  # serverInfo and advertisements first, then our answer or the close
                        msg = await ws.receive(timeout=10)
                        if msg.type != aiohttp.WSMsgType.TEXT:
                            assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED), msg
                            break
                        if json.loads(msg.data)["op"] == "status":
                            break
                    await ws.close()
            # 120 connections of the deepest kind, as in the issue (2,289 journal lines there)
            for _ in range(60):
                for url, protocols in ((daemon.rosbridge_url, ()), (daemon.foxglove_url, ("foxglove.websocket.v1",))):
                    ws = await http.ws_connect(url, protocols=protocols)
                    await ws.send_str('{"op":"publish","topic":"/x","msg":{"a":' + nested(5_000) + "}}")
                    await ws.close()
            # the daemon still serves both
            ws = await http.ws_connect(daemon.rosbridge_url)
            await ws.send_str(json.dumps({"op": "call_service", "id": "t", "service": "/rosapi/get_time"}))
            assert json.loads((await ws.receive(timeout=10)).data)["result"]
            await ws.close()

    with Watch(daemon) as watch:
        asyncio.run(main())
    log = daemon.log()
    print(watch)
    print(log[-3000:])
    assert "Traceback" not in log and "RecursionError" not in log
    assert len(log.splitlines()) < 60, len(log.splitlines())
    assert watch.worst < 1.0 and watch.failed == 0, watch


def test_a_deep_parameter_set_by_a_client_cannot_break_the_master(daemon: WebDaemon) -> None:
    """A value nested 900 deep decodes within Python's limit, but every later getParam of it would not."""
    from tests.reliability.floods import get_pid

    async def main() -> None:
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(daemon.foxglove_url, protocols=["foxglove.websocket.v1"])
            await ws.send_str('{"op":"setParameters","parameters":[{"name":"/deep","value":' + nested(900) + "}]}")
            await ws.send_str('{"op":"getParameters","parameterNames":["/deep"],"id":"r"}')
            async with backports.timeout(10):
                while True:
                    reply = json.loads((await ws.receive()).data)
                    if reply["op"] == "parameterValues" or reply["op"] == "status":
                        break
            await ws.close()

    asyncio.run(main())
    import xmlrpc.client

    with xmlrpc.client.ServerProxy(daemon.uri) as proxy:
        _, _, names = proxy.getParamNames("/t")
    assert "/deep" not in names
    assert get_pid(daemon.uri, 2.0)[0] == 1
    assert "Traceback" not in daemon.log()


PUBLISHER = """
import asyncio, sys
import mrosd
from mrosd.msg import get_message_class
UInt8MultiArray = get_message_class("std_msgs/UInt8MultiArray")
async def main():
    async with mrosd.Node("big_talker", master_uri=sys.argv[1], argv=[], host="127.0.0.1") as node:
        pub = await node.advertise("/big", UInt8MultiArray, latch=True)
        await pub.publish(UInt8MultiArray(data=bytes(range(256)) * (2 * 1024 * 1024 // 256)))
        print("published", flush=True)
        await asyncio.sleep(3600)
asyncio.run(main())
"""


def test_fragment_size_one_on_a_2mb_topic_costs_neither_memory_nor_the_master(
    daemon: WebDaemon, tmp_path: Path
) -> None:
    import sys

    procs = Processes(tmp_path)
    talker = procs.start([sys.executable, "-c", PUBLISHER, daemon.uri], None)
    try:
        assert talker.stdout is not None
        assert talker.stdout.readline().strip() == b"published"
        stop = threading.Event()

        async def main() -> None:
            async with aiohttp.ClientSession() as http:
                clients = []
                for i in range(3):
                    ws = await http.ws_connect(daemon.rosbridge_url, max_msg_size=0)
                    await ws.send_str(
                        json.dumps({"op": "subscribe", "id": f"s{i}", "topic": "/big", "fragment_size": 1})
                    )
                    clients.append(ws)
                # one reads a little, slowly; the others never read
                got = 0
                async with backports.timeout(30):
                    while got < 2000:
                        msg = await clients[0].receive()
                        assert msg.type == aiohttp.WSMsgType.TEXT, msg
                        op = json.loads(msg.data)
                        assert op["op"] == "fragment", op
                        got += 1
                await asyncio.sleep(4)
                for ws in clients:
                    await ws.close()
                stop.set()

        with Watch(daemon) as watch:
            asyncio.run(main())
        print(watch)
        assert watch.worst < 1.0 and watch.failed == 0, watch
        assert watch.growth < 256 * MiB, watch
    finally:
        procs.close()
