"""Faults with real processes: nodes and the master killed with SIGKILL, a publisher cut mid-frame."""

from __future__ import annotations

import asyncio
import struct
import subprocess
from pathlib import Path

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class
from mrosd.wire.header import decode_header, encode_header
from mrosd.xmlrpc import XmlRpcClient, XmlRpcServer
from tests.reliability.relnodes import (
    LISTENER,
    TALKER,
    kill9,
    node_env,
    start_master,
    topic_nodes,
    wait_until,
)
from tests.rosenv import Processes, iter_lines_until

String = get_message_class("std_msgs/String")


def ints(proc: subprocess.Popen[bytes], count: int, timeout: float = 20.0) -> list[int]:
    return [int(line) for line in iter_lines_until(proc, count, timeout)]


def test_a_master_killed_and_restarted_gets_every_node_back_and_new_subscribers_connect(
    procs: Processes, tmp_path: Path
) -> None:
    master, uri = start_master(procs)
    port = uri.rsplit(":", 1)[1].strip("/")
    env = node_env(uri, tmp_path)
    talker = procs.our_python(["-c", TALKER, "/chatter", "50", "talker"], env)
    assert next(iter_lines_until(talker, 1, 20.0)) == "ready"
    first = procs.our_python(["-c", LISTENER, "/chatter", "listener1"], env)
    before = ints(first, 5)
    assert before == sorted(before)

    kill9(master)
    during = ints(first, 5)  # topics are peer to peer: the existing connection does not need the master
    assert during[0] > before[-1]

    start_master(procs, int(port))
    wait_until(
        lambda: topic_nodes(uri, "/chatter") == ({"/talker"}, {"/listener1"}),
        15.0,
        "talker and listener1 re-registered with the new master",
    )
    second = procs.our_python(["-c", LISTENER, "/chatter", "listener2"], env)
    assert len(ints(second, 3)) == 3
    after = ints(first, 3)
    assert after[0] > during[-1]


def test_a_killed_subscriber_is_dropped_and_the_publisher_keeps_serving_the_others(
    procs: Processes, tmp_path: Path
) -> None:
    _, uri = start_master(procs)
    env = node_env(uri, tmp_path)
    talker = procs.our_python(["-c", TALKER, "/chatter", "100", "talker"], env)
    assert next(iter_lines_until(talker, 1, 20.0)) == "ready"
    victim = procs.our_python(["-c", LISTENER, "/chatter", "victim"], env)
    survivor = procs.our_python(["-c", LISTENER, "/chatter", "survivor"], env)
    ints(victim, 3)
    ints(survivor, 3)
    kill9(victim)
    got = ints(survivor, 30)
    assert got == sorted(got) and got[-1] - got[0] >= 29


async def test_a_publisher_dying_in_the_middle_of_a_frame_delivers_only_whole_messages_and_is_followed_by_the_next(
    procs: Processes, tmp_path: Path
) -> None:
    """A hand-made publisher sends one whole frame and half of the next, then its process 'dies' (RST)."""
    _, uri = start_master(procs)
    body = String(data="whole").serialize()
    cut = asyncio.Event()

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        (n,) = struct.unpack("<I", await reader.readexactly(4))
        request = decode_header(await reader.readexactly(n))
        reply = {"callerid": "/liar", "md5sum": String._md5sum, "type": String._type, "latching": "0",
                 "message_definition": String._full_text, "topic": request["topic"]}  # fmt: skip
        writer.write(encode_header(reply))
        half = String(data="never-complete" * 100).serialize()
        writer.write(struct.pack("<I", len(body)) + body + struct.pack("<I", len(half)) + half[: len(half) // 2])
        await writer.drain()
        writer.transport.abort()  # like a SIGKILL: no more bytes, connection reset
        cut.set()

    tcp = await asyncio.start_server(serve, "127.0.0.1", 0)
    tcp_port = tcp.sockets[0].getsockname()[1]

    async def request_topic(caller: str, topic: str, protocols: list[object]) -> list[object]:
        return [1, "", ["TCPROS", "127.0.0.1", tcp_port]]

    async def get_pid(caller: str) -> list[object]:
        return [1, "", 1]

    slave = XmlRpcServer({"requestTopic": request_topic, "getPid": get_pid}, "127.0.0.1", 0)
    async with slave, tcp, XmlRpcClient() as rpc:
        liar_api = f"http://127.0.0.1:{slave.port}/"
        await rpc.call(uri, "registerPublisher", "/liar", "/cut", String._type, liar_api, timeout=5)
        async with mrosd.Node("victim_sub", master_uri=uri, host="127.0.0.1") as node:
            received: list[str] = []
            sub = await node.subscribe("/cut", String, callback=lambda m: received.append(m.data))
            await backports.wait_for(cut.wait(), 10)
            # then a real publisher appears: the subscriber is still healthy and follows it
            pub = await node.advertise("/cut", String)
            await rpc.call(uri, "unregisterPublisher", "/liar", "/cut", liar_api, timeout=5)
            for _ in range(200):
                await pub.publish(String(data="next"))
                if "next" in received:
                    break
                await asyncio.sleep(0.02)
            assert received[0] == "whole"
            assert set(received) == {"whole", "next"}, received[:5]
            del sub


BIG_TALKER = """
import asyncio, sys, mrosd
from mrosd.msg import get_message_class
Image = get_message_class("sensor_msgs/Image")
async def main():
    async with mrosd.Node("big_talker", argv=[], watchdog_interval=0.2) as node:
        pub = await node.advertise("/images", Image, queue_size=4)
        print("ready", flush=True)
        n = 0
        while True:
            n += 1
            data = bytes([n % 251]) * (2 << 20)
            await pub.publish(Image(height=n, width=1024, step=2048, encoding="mono16", data=data))
            await asyncio.sleep(0)
asyncio.run(main())
"""


async def test_a_publisher_process_killed_while_streaming_2_mb_images_never_delivers_a_partial_one(
    procs: Processes, tmp_path: Path
) -> None:
    _, uri = start_master(procs)
    env = node_env(uri, tmp_path)
    image = get_message_class("sensor_msgs/Image")
    got: list[tuple[int, int, bool]] = []
    first = asyncio.Event()

    def on_image(msg: object) -> None:
        data = bytes(msg.data)  # type: ignore[attr-defined]
        n = msg.height  # type: ignore[attr-defined]
        got.append((n, len(data), data == bytes([n % 251]) * len(data)))
        first.set()

    async with mrosd.Node("image_sink", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        await node.subscribe("/images", image, callback=on_image)
        talker = procs.our_python(["-c", BIG_TALKER], env)
        assert await asyncio.to_thread(lambda: next(iter_lines_until(talker, 1, 20.0))) == "ready"
        await backports.wait_for(first.wait(), 20)
        await asyncio.sleep(0.3)
        kill9(talker)  # at a random point of a 2 MiB frame, most likely
        await asyncio.sleep(0.5)
        count = len(got)
        assert count >= 1
        assert all(length == 2 << 20 and whole for _, length, whole in got), "a partial or mixed image was delivered"
        # a new publisher process on the same topic is followed
        first.clear()
        talker = procs.our_python(["-c", BIG_TALKER], env)
        await backports.wait_for(first.wait(), 20)
        assert len(got) > count
