"""What the web part gained after issue 31, attacked as a hostile admitted client against a real daemon (one
per module): ``x-mrosd.imageSettings`` and ``x-mrosd.subscribeDelivery`` flooded with hostile values,
permessage-deflate offered with hostile parameters and HTTP a parser refuses, and the dead-man switch hit by
clients that connect, drive and vanish in a loop. The bar of issue 31 throughout: the master answers getPid
within 1 s, the daemon's RSS grows < 256 MiB, a refusal is one (rate-limited) line, never a traceback.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from mrosd import backports
from tests.rosenv import Processes
from tests.web.webdaemon import CmdVelCounter, MiB, Watch, WebDaemon

FOXGLOVE = ["foxglove.websocket.v1"]
CAMERA = "/cam/image"

#: an Image topic at 10 Hz, so the hub offers ``/cam/image/compressed``
CAMERA_NODE = """
import asyncio, sys
import mrosd
from mrosd.msg import get_message_class
Image = get_message_class("sensor_msgs/Image")
async def main():
    async with mrosd.Node("cam", master_uri=sys.argv[1], argv=[], host="127.0.0.1") as node:
        pub = await node.advertise(sys.argv[2], Image)
        print("ready", flush=True)
        while True:
            await pub.publish(Image(height=8, width=8, encoding="mono8", step=8, data=bytes(64)))
            await asyncio.sleep(0.1)
asyncio.run(main())
"""


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDaemon]:
    tmp = tmp_path_factory.mktemp("doors")
    procs = Processes(tmp)
    run = WebDaemon(procs, tmp)
    camera = procs.start([sys.executable, "-c", CAMERA_NODE, run.uri, CAMERA], None)
    assert camera.stdout is not None and camera.stdout.readline().strip() == b"ready"
    yield run
    run.close()
    procs.close()


def _quiet(log: str) -> list[str]:
    return [line for line in log.splitlines() if not line.startswith("<6>")]


async def _until_advertised(ws: aiohttp.ClientWebSocketResponse, topic: str) -> int:
    async with backports.timeout(20):
        while True:
            msg = await ws.receive()
            assert msg.type == aiohttp.WSMsgType.TEXT, msg
            op = json.loads(msg.data)
            if op["op"] == "advertise":
                for channel in op["channels"]:
                    if channel["topic"] == topic:
                        return int(channel["id"])


def test_hostile_image_settings_and_delivery_ops_are_refused_and_hold_nothing(daemon: WebDaemon) -> None:
    """Out-of-range, ill-typed and non-JSON values, a 1 MB topic name, topics that are not made here, 20,000
    distinct topics, then 100,000 ``subscribeDelivery`` ops: each settings op is one status reply, nothing is
    kept for a topic that is not an offered ``T/compressed``, and the topic's own settings still work."""
    virtual = CAMERA + "/compressed"
    hostile: list[dict[str, Any] | str] = [
        {"topic": virtual, "maxWidth": 10**9},
        {"topic": virtual, "maxWidth": -1},
        {"topic": virtual, "maxWidth": 1},
        {"topic": virtual, "quality": 1000},
        {"topic": virtual, "quality": 0},
        {"topic": virtual, "maxRate": 1e6},
        {"topic": virtual, "maxRate": -1},
        {"topic": virtual, "maxRate": "fast"},
        {"topic": virtual, "quality": 5.5},
        {"topic": "/x" * 400_000, "quality": 5},
        {"topic": "/rosout", "quality": 5},
        {"topic": CAMERA, "quality": 5},
        {"topic": 7, "quality": 5},
        f'{{"op":"x-mrosd.imageSettings","topic":"{virtual}","maxRate":NaN}}',
        f'{{"op":"x-mrosd.imageSettings","topic":"{virtual}","maxRate":1e999}}',
    ]
    distinct = 20_000

    async def main() -> None:
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(daemon.foxglove_url, protocols=FOXGLOVE, max_msg_size=0)
            await _until_advertised(ws, virtual)
            replies: list[dict[str, Any]] = []
            want = len(hostile) + distinct + 1

            async def read() -> None:
                while len(replies) < want:
                    msg = await ws.receive()
                    assert msg.type == aiohttp.WSMsgType.TEXT, msg
                    op = json.loads(msg.data)
                    if op["op"] in ("status", "x-mrosd.imageSettings"):
                        replies.append(op)

            reader = asyncio.create_task(read())
            for op in hostile:
                await ws.send_str(op if isinstance(op, str) else json.dumps({"op": "x-mrosd.imageSettings", **op}))
            for i in range(distinct):
                await ws.send_str(
                    json.dumps({"op": "x-mrosd.imageSettings", "topic": f"/t{i}/compressed", "quality": 5})
                )
            for _ in range(100_000):
                await ws.send_str('{"op":"x-mrosd.subscribeDelivery"}')
            await ws.send_str(json.dumps({"op": "x-mrosd.imageSettings", "topic": virtual, "quality": 42}))
            async with backports.timeout(60):
                await reader
            errors = [r for r in replies if r["op"] == "status"]
            assert len(errors) == len(hostile) + distinct, [r for r in replies if r["op"] != "status"]
            assert all(r["level"] == 2 and len(r["message"]) < 1_000_000 for r in errors)
            assert replies[-1] == {
                "op": "x-mrosd.imageSettings",
                "topic": virtual,
                "quality": 42,
                "maxWidth": 0,
                "maxRate": 0.0,
            }, replies[-1]
            await ws.close()

    with Watch(daemon) as watch:
        asyncio.run(main())
    print(watch)
    assert watch.worst < 1.0 and watch.failed == 0, watch
    assert watch.growth < 256 * MiB, watch
    log = daemon.log()
    assert "Traceback" not in log


def _frame(payload: bytes, opcode: int = 1, rsv1: bool = False) -> bytes:
    """One masked client frame (FIN set)."""
    mask = os.urandom(4)
    size = len(payload)
    head = bytes([0x80 | (0x40 if rsv1 else 0) | opcode])
    if size < 126:
        head += bytes([0x80 | size])
    else:
        head += bytes([0x80 | 127]) + size.to_bytes(8, "big")
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


async def _handshake(port: int, extensions: str, protocol: str | None, then: bytes = b"") -> tuple[str, bytes]:
    """A raw WebSocket handshake offering ``extensions``; (status line, what the server sent: its answer, and
    with ``then`` sent after the handshake, what follows until the server closes, at most 2 s)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    key = base64.b64encode(os.urandom(16)).decode()
    request = (
        f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Extensions: {extensions}\r\n"
    )
    if protocol:
        request += f"Sec-WebSocket-Protocol: {protocol}\r\n"
    writer.write(request.encode() + b"\r\n" + then)
    got = b""
    try:
        async with backports.timeout(2):
            got = await reader.readuntil(b"\r\n\r\n")
            while then and (chunk := await reader.read(65536)):
                got += chunk
    except (TimeoutError, asyncio.IncompleteReadError):
        pass
    writer.close()
    return got.split(b"\r\n", 1)[0].decode(), got


HOSTILE_OFFERS = [
    "permessage-deflate; client_max_window_bits=8",
    "permessage-deflate; server_max_window_bits=8",
    "permessage-deflate; client_max_window_bits=8; server_max_window_bits=8; server_no_context_takeover",
    "permessage-deflate; server_max_window_bits=0",
    "permessage-deflate; server_max_window_bits=99",
    "permessage-deflate; client_max_window_bits=x",
    "permessage-deflate; server_no_context_takeover; server_no_context_takeover",
    "permessage-deflate, permessage-deflate; client_max_window_bits=9, x-webkit-deflate-frame",
    "permessage-deflate; " + "a=b; " * 4000,  # a header line past aiohttp's 8 KiB
]


def test_hostile_deflate_offers_and_unparsable_http_are_one_line_each(daemon: WebDaemon) -> None:
    """Each offer gets a handshake with or without deflate (never a broken one), a header line past the
    parser's limit gets 400; 100 such requests are a few log lines in all, no traceback (aiohttp logged each
    with its traceback at ERROR). Clients that negotiate deflate and go at once leave nothing unretrieved
    (deterministic in ``test_reliability_web_doors_inproc.py``)."""

    async def main() -> None:
        ports = ((daemon.foxglove_port, "foxglove.websocket.v1"), (daemon.rosbridge_port, None))
        for port, protocol in ports:
            for offer in HOSTILE_OFFERS:
                status, _ = await _handshake(port, offer, protocol)
                assert status in ("HTTP/1.1 101 Switching Protocols", "HTTP/1.0 400 Bad Request"), (offer, status)
            # a frame marked compressed on a connection that did not negotiate deflate: a protocol error close
            _, got = await _handshake(port, "x-nothing", protocol, _frame(b"\x00", rsv1=True))
            assert b"\x88\x02\x03\xea" in got, got[-20:]
            for _ in range(50):
                status, _ = await _handshake(port, HOSTILE_OFFERS[-1], protocol)
                assert status == "HTTP/1.0 400 Bad Request", status
            for _ in range(30):
                status, _ = await _handshake(port, "permessage-deflate", protocol)
                assert status == "HTTP/1.1 101 Switching Protocols", status

    before = len(_quiet(daemon.log()))
    with Watch(daemon) as watch:
        asyncio.run(main())
    print(watch)
    lines = _quiet(daemon.log())[before:]
    print("\n".join(lines[-20:]))
    assert not any(line.startswith("<3>") for line in lines), lines
    assert sum("malformed HTTP request" in line for line in lines) <= 6, lines
    assert watch.worst < 1.0 and watch.failed == 0, watch


TWIST = {"linear": {"x": 0.5, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.3}}


def test_clients_that_drive_and_vanish_in_a_loop_cost_one_zero_each_and_nothing_stays(daemon: WebDaemon) -> None:
    """300 rosbridge clients, 20 at a time: each advertises /cmd_vel, publishes one moving Twist and drops its
    connection without a close. Each is followed by its one zero (no more), the daemon's tasks and threads come
    back to where they were, getPid stays under 1 s."""
    clients, at_once = 300, 20

    async def drive_and_vanish(http: aiohttp.ClientSession) -> None:
        ws = await http.ws_connect(daemon.rosbridge_url)
        await ws.send_str(json.dumps({"op": "advertise", "topic": "/cmd_vel", "type": "geometry_msgs/Twist"}))
        await ws.send_str(json.dumps({"op": "publish", "topic": "/cmd_vel", "msg": TWIST}))
        await asyncio.sleep(0.05)
        transport = ws._response.connection.transport if ws._response.connection else None
        assert transport is not None
        transport.abort()  # no close frame: the browser was killed

    async def main() -> None:
        async with aiohttp.ClientSession() as http:
            for _ in range(clients // at_once):
                await asyncio.gather(*(drive_and_vanish(http) for _ in range(at_once)))

    threads0 = _threads(daemon)
    with CmdVelCounter(daemon.uri) as counter, Watch(daemon) as watch:
        asyncio.run(main())
        # every client's Twist and its zero (the first few Twists may come before the counter's connection)
        assert counter.wait_for(2 * clients - 20, 30), counter.count
    print(watch, "received", counter.count)
    log = daemon.log()
    assert counter.count <= 2 * clients + 5, counter.count
    assert log.count("dead-man") >= 1 and "Traceback" not in log
    assert watch.worst < 1.0 and watch.failed == 0, watch
    assert watch.growth < 256 * MiB, watch
    assert _threads(daemon) <= threads0 + 4, (threads0, _threads(daemon))


def _threads(daemon: WebDaemon) -> int:
    text = Path(f"/proc/{daemon.proc.pid}/status").read_text()
    return int(text.split("Threads:")[1].split()[0])


#: ``n`` nodes, each latching one message of ``mb`` MiB on /big (a latched map, a point cloud, an image)
LATCHERS = """
import asyncio, sys
import mrosd
from mrosd.msg import get_message_class
U8 = get_message_class("std_msgs/UInt8MultiArray")
async def main():
    n, mb = int(sys.argv[2]), int(sys.argv[3])
    nodes = []
    for i in range(n):
        node = mrosd.Node(f"latcher_{i}", master_uri=sys.argv[1], argv=[], host="127.0.0.1")
        await node.start()
        pub = await node.advertise("/big", U8, latch=True)
        await pub.publish(U8(data=bytes([i]) * (mb * 1024 * 1024)))
        nodes.append((node, pub))
    print("ready", flush=True)
    await asyncio.sleep(3600)
asyncio.run(main())
"""


def test_big_latched_messages_of_many_publishers_are_remembered_within_a_byte_bound(tmp_path: Path) -> None:
    """10 publishers each latch 10 MiB on /big; two Foxglove clients subscribe one after the other (the second
    is replayed what the hub remembered). Before: the hub kept a copy of every latched body, without a byte
    bound (this test +301 MiB; 6 x 40 MiB and 4 clients +720 MiB); now it holds the received bodies (no copy)
    and at most 64 MiB of them over all topics, newest first (+201 MiB; 6 x 40 MiB and 4 clients +480 MiB:
    what stays is each TCPROS link's receive buffer of its big message)."""
    procs = Processes(tmp_path)
    fresh = WebDaemon(procs, tmp_path)  # its own: the RSS peak of this attack alone
    try:
        latchers = procs.start([sys.executable, "-c", LATCHERS, fresh.uri, "10", "10"], None)
        assert latchers.stdout is not None and latchers.stdout.readline().strip() == b"ready"

        async def main() -> list[int]:
            counts = []
            async with aiohttp.ClientSession() as http:
                for _ in range(2):
                    ws = await http.ws_connect(fresh.foxglove_url, protocols=FOXGLOVE, max_msg_size=0)
                    channel = await _until_advertised(ws, "/big")
                    await ws.send_str(
                        json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channel}]})
                    )
                    got = 0
                    with contextlib.suppress(TimeoutError):
                        while got < 10:
                            msg = await ws.receive(timeout=1.5)
                            got += msg.type == aiohttp.WSMsgType.BINARY
                    counts.append(got)
            return counts

        with Watch(fresh) as watch:
            counts = asyncio.run(main())
        print(watch, "messages per client", counts)
        assert all(c >= 1 for c in counts), counts  # each client gets the topic's latched data
        assert watch.growth < 256 * MiB, watch
        assert watch.worst < 1.0 and watch.failed == 0, watch
    finally:
        fresh.close()
        procs.close()


#: A /tf publisher inventing frames and stamps: messages of ``per`` transforms as fast as it can, for
#: ``seconds``; then one message whose transform count claims 10^9.
TF_FLOOD = """
import asyncio, sys, time
import mrosd
from mrosd.msg import get_message_class
TFMessage = get_message_class("tf2_msgs/TFMessage")
TS = get_message_class("geometry_msgs/TransformStamped")
async def main():
    per, seconds = int(sys.argv[2]), float(sys.argv[3])
    async with mrosd.Node("tf_flood", master_uri=sys.argv[1], argv=[], host="127.0.0.1") as node:
        pub = await node.advertise("/tf", TFMessage, queue_size=4)
        await pub.wait_for_subscribers(1, timeout=30)
        started, k, base = time.monotonic(), 0, time.time_ns()
        while time.monotonic() - started < seconds:
            ts = []
            for j in range(per):
                t = TS(child_frame_id=f"f{(k * per + j) % 10000}")
                t.header.frame_id = "world"
                stamp = base + k * 1000
                t.header.stamp.secs, t.header.stamp.nsecs = stamp // 10**9, stamp % 10**9
                t.transform.rotation.w = 1.0
                ts.append(t)
            await pub.publish(TFMessage(transforms=ts))
            k += 1
        pub.publish_serialized((10**9).to_bytes(4, "little") + bytes(60))
        print("sent", k * per, flush=True)
        await asyncio.sleep(3600)
asyncio.run(main())
"""


def test_a_tf_flood_while_a_web_client_uses_the_republisher_does_not_hold_the_master(
    daemon: WebDaemon, tmp_path: Path
) -> None:
    """A rosbridge client asks ``/republish_tfs`` (the daemon's Buffer then follows /tf), and a rogue node
    publishes 1,000-transform messages of ever new frames and stamps for 6 s, then one claiming 10^9
    transforms. Before: the Buffer stored each message on the loop as it came (getPid 5 s, the daemon's own
    nodes lost the master, +250 MiB in 15 s and growing); now an inbox bounded in bytes, a storing task that
    yields every 5 ms, and 250,000 entries for all frames together."""
    request = {
        "source_frames": ["f1"],
        "target_frame": "world",
        "angular_thres": 0,
        "trans_thres": 0,
        "rate": 10,
        "timeout": {"secs": 60, "nsecs": 0},
    }

    async def ask() -> None:
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(daemon.rosbridge_url)
            await ws.send_str(
                json.dumps({"op": "call_service", "id": "r", "service": "/republish_tfs", "args": request})
            )
            reply = json.loads((await ws.receive(timeout=10)).data)
            assert reply["result"] is True, reply
            await ws.close()

    asyncio.run(ask())
    procs = Processes(tmp_path)
    try:
        with Watch(daemon) as watch:
            flood = procs.start([sys.executable, "-c", TF_FLOOD, daemon.uri, "1000", "6"], None)
            assert flood.stdout is not None
            sent = flood.stdout.readline().decode()
            asyncio.run(ask())  # the republisher still answers
        print(watch, sent.strip())
        assert sent.startswith("sent"), sent
        assert watch.worst < 1.0 and watch.failed == 0, watch
        assert watch.growth < 256 * MiB, watch
        log = daemon.log()
        assert "Traceback" not in log
        assert log.count("claims 1000000000 transforms") == 1
    finally:
        procs.close()
