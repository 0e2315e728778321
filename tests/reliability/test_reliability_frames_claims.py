"""Fake publishers announce 1 GiB frames and send 5 bytes: the subscriber's memory must follow data, not claims.

The victim is a real mrosd subscriber process; three fake publishers (a stdlib XML-RPC slave and raw
sockets in this test) each send a valid connection header, one small honest frame (so the test knows
the victim has read this far), then a 1 GiB length prefix and 5 bytes, and keep the connection open.
The victim's peak RSS must grow by megabytes, not gigabytes, and it must keep running.
"""

from __future__ import annotations

import socket
import struct
import subprocess
import threading
import time
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path
from xmlrpc.server import SimpleXMLRPCRequestHandler, SimpleXMLRPCServer

import pytest

from mrosd.msg import get_message_class
from mrosd.wire.header import ConnectionHeader, encode_header
from tests.reliability.relnodes import node_env, start_master
from tests.rosenv import Processes, iter_lines_until

String = get_message_class("std_msgs/String")
GIB = 1024 * 1024 * 1024
FAKES = 3
#: Allowed peak RSS growth of the victim for all three fakes together.
ALLOWED_GROWTH = 64 * 1024 * 1024

VICTIM = """
import asyncio, sys, mrosd
from mrosd.msg import get_message_class
String = get_message_class("std_msgs/String")
async def main():
    async with mrosd.Node("victim", host="127.0.0.1") as node:
        await node.subscribe("/victim", String, callback=lambda m: print(m.data, flush=True))
        print("ready", flush=True)
        await asyncio.Event().wait()
asyncio.run(main())
"""


def _rss_fields(pid: int) -> dict[str, int]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            out[key] = int(value.split()[0]) * 1024
    return out


class _AnyPath(SimpleXMLRPCRequestHandler):
    rpc_paths = ()  # every path is an RPC path: one server stands for three publisher URIs

    def log_message(self, format: str, *args: object) -> None:
        pass


class FakePublishers:
    """A slave API answering requestTopic and a TCPROS port that sends a claim it never honours."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.tcp_port = self.listener.getsockname()[1]
        self.rpc = SimpleXMLRPCServer(("127.0.0.1", 0), requestHandler=_AnyPath, logRequests=False)
        self.rpc.register_function(self._request_topic, "requestTopic")
        self.rpc_port = self.rpc.server_address[1]
        self.conns: list[socket.socket] = []
        self.served = 0
        self._threads = [
            threading.Thread(target=self.rpc.serve_forever, daemon=True),
            threading.Thread(target=self._accept, daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def _request_topic(self, caller_id: str, topic: str, protocols: list[object]) -> list[object]:
        return [1, "", ["TCPROS", "127.0.0.1", self.tcp_port]]

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            self.conns.append(conn)
            conn.settimeout(10)
            length = struct.unpack("<I", _read_exact(conn, 4))[0]
            _read_exact(conn, length)  # the subscriber's header
            self.served += 1
            reply = encode_header(
                ConnectionHeader(
                    callerid=f"/fake{self.served}",
                    md5sum=String._md5sum,
                    type=String._type,
                    message_definition=String._full_text,
                    latching="0",
                )
            )
            hello = String(data=f"hello{self.served}").serialize()
            # A small honest frame, then the claim: 1 GiB announced, 5 bytes sent, the connection kept open.
            conn.sendall(reply + struct.pack("<I", len(hello)) + hello + struct.pack("<I", GIB) + b"12345")

    def uri(self, index: int) -> str:
        return f"http://127.0.0.1:{self.rpc_port}/fake{index}"

    def close(self) -> None:
        self.rpc.shutdown()
        self.rpc.server_close()
        self.listener.close()
        for conn in self.conns:
            conn.close()


def _read_exact(conn: socket.socket, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = conn.recv(count - len(data))
        if not chunk:
            raise ConnectionError("subscriber closed")
        data += chunk
    return data


@pytest.fixture
def fakes() -> Iterator[FakePublishers]:
    fake = FakePublishers()
    yield fake
    fake.close()


def test_announced_gigabyte_frames_cost_no_memory(procs: Processes, tmp_path: Path, fakes: FakePublishers) -> None:
    _, master = start_master(procs)
    victim = procs.our_python(["-c", VICTIM], node_env(master, tmp_path), stderr=subprocess.DEVNULL)
    lines = iter_lines_until(victim, 1 + FAKES, 60)
    assert next(lines) == "ready"
    baseline = _rss_fields(victim.pid)["VmRSS"]
    with xmlrpc.client.ServerProxy(master) as proxy:
        for index in range(1, FAKES + 1):
            code, msg, _ = proxy.registerPublisher(f"/fake{index}", "/victim", String._type, fakes.uri(index))
            assert code == 1, msg
            assert next(lines) == f"hello{index}"
    # The claim sits in the same segment as the hello frame; give a straddling read a moment to land.
    deadline = time.monotonic() + 0.5
    while time.monotonic() < deadline:
        growth = _rss_fields(victim.pid)["VmHWM"] - baseline
        assert growth < ALLOWED_GROWTH, f"victim's peak RSS grew by {growth / 2**20:.0f} MiB for {FAKES * 5} bytes"
        time.sleep(0.05)
    assert victim.poll() is None, "the victim died"
