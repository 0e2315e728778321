"""The servers facing untrusted peers keep answering, whatever one client sends: XML-RPC and the IXM daemon.

Each server runs on a real socket in a background event loop; hypothesis sends bodies from the parser targets,
and after every one a well-formed call from a fresh client must still be answered correctly.
"""

from __future__ import annotations

import asyncio
import http.client
import socket
import struct
import threading
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from mrosd.xmlrpc import MAX_BODY_SIZE, Fault, XmlRpcServer, decode_response, encode_call
from tests.fuzz.targets import ixm_bodies, xmlrpc_bodies

FUZZ = settings(
    max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), database=None, derandomize=True
)


class LoopThread:
    """An asyncio loop in a thread, so that a synchronous hypothesis test can talk to a server on it."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, factory: Callable[[], Coroutine[Any, Any, Any]], timeout: float = 10.0) -> Any:
        return asyncio.run_coroutine_threadsafe(factory(), self.loop).result(timeout)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def xmlrpc_port() -> Iterator[int]:
    async def get_pid(caller: str) -> list[object]:
        return [1, "", 4242]

    lt = LoopThread()
    server = XmlRpcServer({"getPid": get_pid}, "127.0.0.1", 0)
    lt.run(server.start)
    try:
        yield server.port
    finally:
        lt.run(server.aclose)
        lt.close()


def post(port: int, body: bytes) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("POST", "/", body, {"Content-Type": "text/xml"})
        reply = conn.getresponse()
        return reply.status, reply.read()
    finally:
        conn.close()


def test_the_xmlrpc_server_answers_every_body_and_keeps_serving(xmlrpc_port: int) -> None:
    @FUZZ
    @given(xmlrpc_bodies)
    def run(body: bytes) -> None:
        status, answer = post(xmlrpc_port, body)
        assert status == 200, answer[:300]
        try:
            decode_response(answer)
        except Fault:  # a fault is the expected answer to a bad body; anything else means a malformed answer
            pass
        status, answer = post(xmlrpc_port, encode_call("getPid", ("/probe",)))
        assert status == 200 and decode_response(answer) == [1, "", 4242]

    run()


def test_an_xmlrpc_body_over_max_body_size_gets_a_fault_and_the_server_keeps_serving(xmlrpc_port: int) -> None:
    size = MAX_BODY_SIZE + 1
    chunk = b"<" * (1 << 20)
    with socket.create_connection(("127.0.0.1", xmlrpc_port), timeout=20) as s:
        s.sendall(f"POST / HTTP/1.1\r\nHost: x\r\nContent-Type: text/xml\r\nContent-Length: {size}\r\n\r\n".encode())
        sent = 0
        try:
            while sent < size:
                n = min(len(chunk), size - sent)
                s.sendall(chunk[:n])
                sent += n
        except (BrokenPipeError, ConnectionResetError):
            pass  # the server may stop reading once the limit is passed
        answer = s.recv(65536)
    assert answer.startswith(b"HTTP/1.1 "), answer[:200]
    assert b" 413 " in answer[:20] or b"exceeds" in answer, answer[:300]
    status, body = post(xmlrpc_port, encode_call("getPid", ("/probe",)))
    assert status == 200 and decode_response(body) == [1, "", 4242]


def test_the_ixm_daemon_survives_every_request_body_and_keeps_serving(tmp_path: Path) -> None:
    from mrosd.ixm.client import IxmClient
    from mrosd.ixm.server import IxmServer

    path = str(tmp_path / "ixm.sock")
    lt = LoopThread()
    server = IxmServer(path)
    lt.run(server.start)
    try:

        @FUZZ
        @given(ixm_bodies)
        def run(body: bytes) -> None:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as bad:
                bad.settimeout(5)
                bad.connect(path)
                bad.sendall(struct.pack("<I", len(body)) + body)
            with IxmClient(path, name="probe", timeout=5) as good:
                key = good.open("/fuzz/probe", "float64", count=2, mode="rw")
                key.write([1.0, 2.0])
                assert list(key.read()) == [1.0, 2.0]

        run()
    finally:
        lt.run(server.aclose)
        lt.close()
