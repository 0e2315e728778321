"""Large frames written with writev, cut anywhere by a subscriber that stops reading, arrive whole and in order.

A raw-socket subscriber with a tiny receive buffer handshakes and then reads nothing while the publisher
sends images larger than the socket can take: the first frame is cut by a short ``writev``, the rest of it
goes through the transport, later frames queue (drop-oldest). When the reader finally drains the socket,
every frame it gets must be one of the published images, byte for byte, in publishing order.
"""

from __future__ import annotations

import asyncio
import socket
import struct

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class
from mrosd.wire.header import ConnectionHeader, encode_header
from tests.reliability.relnodes import start_master
from tests.rosenv import Processes

Image = get_message_class("sensor_msgs/Image")
SIZE = 600_000
COUNT = 12


async def _read_exact(reader: asyncio.StreamReader, count: int) -> bytes:
    return await backports.wait_for(reader.readexactly(count), 10)


async def _stalled_subscriber(node: mrosd.Node, topic: str) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """A raw TCPROS subscriber with a 4 KB receive buffer that reads nothing until the test says so."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", node.tcpros_port))
    reader, writer = await asyncio.open_connection(sock=sock)
    header = ConnectionHeader(callerid="/slow", topic=topic, md5sum="*", type="*", tcp_nodelay="1")
    writer.write(encode_header(header))
    (length,) = struct.unpack("<I", await _read_exact(reader, 4))
    await _read_exact(reader, length)  # the publisher's header
    return reader, writer


async def test_cut_large_frames_arrive_whole_and_in_order(procs: Processes) -> None:
    _, uri = start_master(procs)
    async with mrosd.Node("bulk", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        pub = await node.advertise("/bulk", Image, queue_size=4)
        reader, writer = await _stalled_subscriber(node, "/bulk")
        await pub.wait_for_subscribers(1, 10)
        sent = []
        for i in range(COUNT):
            img = Image(height=1, width=SIZE, encoding="mono8", step=SIZE, data=bytes([i + 1]) * SIZE)
            await pub.publish(img)
            sent.append(img.serialize())  # after publish: it set header.seq
        link = pub.links[0]
        assert link.queue or (link.proto.transport is not None and link.proto.transport.get_write_buffer_size())
        got = []
        while len(got) < COUNT - link.dropped:
            (length,) = struct.unpack("<I", await _read_exact(reader, 4))
            got.append(await _read_exact(reader, length))
        # seq differs per message, so each frame identifies exactly one published message
        index_of = {frame: i for i, frame in enumerate(sent)}
        indexes = [index_of.get(frame, -1) for frame in got]  # -1: a frame that was never published
        assert indexes == sorted(indexes) and indexes[0] == 0 and indexes[-1] == COUNT - 1
        writer.close()


async def _check_a_changed_payload_is_sent_as_published(uri: str) -> None:
    async with mrosd.Node("owner", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        pub = await node.advertise("/owned", Image)
        reader, writer = await _stalled_subscriber(node, "/owned")
        await pub.wait_for_subscribers(1, 10)
        filler = Image(height=1, width=SIZE, encoding="mono8", step=SIZE, data=b"f" * SIZE)
        for _ in range(8):  # more than the kernel takes: what follows waits in the transport or the queue
            await pub.publish(filler)
        data = bytearray(b"a" * SIZE)  # the caller's own, mutable buffer
        img = Image(height=1, width=SIZE, encoding="mono8", step=SIZE, data=data)
        await pub.publish(img)
        expected = img.serialize()
        link = pub.links[0]
        assert link.queue or (link.proto.transport is not None and link.proto.transport.get_write_buffer_size())
        data[:] = b"b" * SIZE  # not sent yet: what was published must not change
        for _ in range(9):
            (length,) = struct.unpack("<I", await _read_exact(reader, 4))
            got = await _read_exact(reader, length)
        assert got == expected, f"{got.count(b'b')} bytes of the frame changed after publish()"
        writer.close()


async def test_a_payload_changed_after_publish_is_sent_as_it_was_published(procs: Processes) -> None:
    _, uri = start_master(procs)
    await _check_a_changed_payload_is_sent_as_published(uri)


def test_the_same_on_uvloop_whose_transport_keeps_the_pieces_it_was_given(procs: Processes) -> None:
    uvloop = pytest.importorskip("uvloop")
    _, uri = start_master(procs)
    uvloop.run(_check_a_changed_payload_is_sent_as_published(uri))
