"""Big replies cost what the client reads, once: 20 concurrent callers of a 73 MB getSystemState or a 90 MB
getParam neither multiply the master's memory nor stall its loop, and our own client reads such a reply.

Issue 24: with 70 topics named with 1 MiB names, 20 concurrent getSystemState callers took the master from
115 to 1515 MiB and getPid to 5-10 s, and ``mros topic list`` failed with "response of 73 MB is too big";
100 MB of parameters read by 20 clients: 211 -> 1928 MiB and a getPid timed out after 15 s.
"""

from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

import mrosd.master.httpconn as httpconn
from mrosd import backports
from mrosd.master import Master, MasterClient
from mrosd.master.dispatch import BIG_REPLY, FAULT_REPLY_BUDGET
from mrosd.xmlrpc import Fault, XmlRpcClient, decode_response, encode_call
from tests.reliability.test_reliability_master_http import MasterProcess, post
from tests.rosenv import PROJECT_ROOT, Processes

MIB = 1 << 20


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise AssertionError(field)


def reset_peak(pid: int) -> None:
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # VmHWM := VmRSS (Linux >= 4.0)


def request(method: str, *params: object) -> bytes:
    body = encode_call(method, params)
    return b"POST / HTTP/1.1\r\nContent-Length: %d\r\n\r\n%s" % (len(body), body)


def read_response(sock: socket.socket) -> tuple[bytes, int, bytes]:
    """(status line, body length, the first 1000 bytes of the body); the body is read and dropped."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(1 << 16)
        assert chunk, data
        data += chunk
    head, rest = data.split(b"\r\n\r\n", 1)
    length = next(int(h.split(b":")[1]) for h in head.split(b"\r\n") if h.lower().startswith(b"content-length"))
    first, got = rest[:1000], len(rest)
    while got < length:
        chunk = sock.recv(1 << 20)
        assert chunk
        if len(first) < 1000:
            first += chunk[: 1000 - len(first)]
        got += len(chunk)
    return head.split(b"\r\n", 1)[0], length, first


class Prober(threading.Thread):
    """getPid over a fresh connection every 20 ms; records each round trip (or the failure)."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.times: list[float] = []
        self.failures: list[str] = []
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            start = time.monotonic()
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=2) as s:
                    s.sendall(request("getPid", "/probe"))
                    status, _, body = read_response(s)
                    assert status.endswith(b"200 OK") and b"<int>" in body
            except (OSError, AssertionError) as exc:
                self.failures.append(repr(exc))
            self.times.append(time.monotonic() - start)
            self.stop.wait(0.02)


def flood_of_readers(
    master: MasterProcess, calls: list[bytes], hold: float
) -> tuple[float, Prober, list[socket.socket]]:
    """Send each call on its own connection, read nothing for ``hold`` seconds while probing getPid.

    Returns the master's peak RSS growth (MiB) over that time, the prober, and the sockets (unread).
    """
    reset_peak(master.proc.pid)
    base = rss_mib(master.proc.pid)
    prober = Prober(master.port)
    prober.start()
    socks = []
    for call in calls:
        s = socket.create_connection(("127.0.0.1", master.port), timeout=30)
        s.sendall(call)
        socks.append(s)
    time.sleep(hold)
    grown = rss_mib(master.proc.pid, "VmHWM") - base
    prober.stop.set()
    prober.join(5)
    return grown, prober, socks


def check(master: MasterProcess, grown: float, prober: Prober, reply_mib: float, what: str) -> None:
    slowest = max(prober.times) * 1000
    print(
        f"{what}: peak RSS +{grown:.0f} MiB for a {reply_mib:.0f} MiB reply x 20 callers; "
        f"{len(prober.times)} getPid probes, slowest {slowest:.0f} ms, failures {len(prober.failures)}"
    )
    assert not prober.failures, prober.failures[:3]
    # Alone the slowest probe takes 10-40 ms; beside the rest of the suite on 2 cores it took 206 ms once. The
    # failure this guards against, a loop held by encoding or sending the replies, timed getPid out (seconds).
    assert slowest < 500, f"getPid took {slowest:.0f} ms"
    assert grown < 2 * reply_mib + 32, f"peak RSS grew {grown:.0f} MiB"


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
def test_twenty_getsystemstate_callers_of_a_73_mb_reply(procs: Processes, loop: str) -> None:
    master = MasterProcess(procs, loop=loop, kwargs={"cleanup_interval": 0})  # keep the fake publisher
    for i in range(70):
        topic = f"/t{i:02d}" + "x" * MIB
        reply = decode_response(
            post(
                master.uri, encode_call("registerPublisher", ("/big", topic, "std_msgs/String", "http://127.0.0.1:1/"))
            )
        )
        assert reply[0] == 1
    calls = [request("getSystemState", f"/caller{i}") for i in range(20)]
    grown, prober, socks = flood_of_readers(master, calls, hold=3.0)
    lengths = set()
    for s in socks:  # every caller gets the whole reply, however late it reads
        status, length, _ = read_response(s)
        assert status.endswith(b"200 OK"), status
        lengths.add(length)
        s.close()
    assert len(lengths) == 1 and lengths.pop() > 70 * MIB
    check(master, grown, prober, 73, "getSystemState")

    async def our_client() -> int:
        async with MasterClient(master.uri, "/mros", timeout=60) as client:
            pubs, _, _ = await client.get_system_state()
        return len(pubs)

    assert asyncio.run(our_client()) == 70
    listed = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", master.uri, "topic", "list"],
        capture_output=True,
        timeout=60,
        check=False,
        env={**os.environ, "PYTHONPATH": f"{PROJECT_ROOT}:{PROJECT_ROOT / 'cli'}"},
    )
    assert listed.returncode == 0, listed.stderr.decode()[-500:]  # issue 24: "response of 73 MB is too big"
    assert len(listed.stdout.splitlines()) >= 70


def test_twenty_getparam_callers_of_a_90_mb_namespace_some_never_reading(procs: Processes) -> None:
    master = MasterProcess(procs)
    for key in ("/big/a", "/big/b"):
        assert decode_response(post(master.uri, encode_call("setParam", ("/c", key, "v" * (45 * MIB)))))[0] == 1
    calls = [request("getParam", f"/caller{i}", "/big") for i in range(20)]
    grown, prober, socks = flood_of_readers(master, calls, hold=3.0)
    for i, s in enumerate(socks):
        if i % 2:  # half of them hang up without reading: their share is freed, nothing else breaks
            s.close()
            continue
        status, length, first = read_response(s)
        assert status.endswith(b"200 OK") and length > 90 * MIB and b"<struct>" in first
        s.close()
    check(master, grown, prober, 90, "getParam")


async def raw_call(port: int, method: str, *params: object) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """Send one call and leave the answer unread (a small receive buffer: the kernel takes little of it)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 32 * 1024)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
    reader, writer = await asyncio.open_connection(sock=sock)
    writer.write(request(method, *params))
    await writer.drain()
    return reader, writer


async def test_over_budget_a_caller_gets_a_fault_it_can_act_on_and_a_stalled_reader_is_let_go(
    monkeypatch: Any,
) -> None:
    """Non-readers hold two different big values; a third gets fault -32500 naming the budget; once the master
    lets the stalled readers go (REQUEST_TIMEOUT, shortened here) and the state changes, it is served."""
    monkeypatch.setattr(httpconn, "REQUEST_TIMEOUT", 0.5)
    master_cm = Master("127.0.0.1", 0, advertise="127.0.0.1", idle_timeout=0.4, cleanup_interval=0)
    async with master_cm as master, XmlRpcClient(timeout=30) as client:
        for key in ("/a", "/b", "/c"):
            assert (await client.call(master.uri, "setParam", "/t", key, key * (8 * MIB)))[0] == 1
        handler = master._handler
        stalled = [await raw_call(master.port, "getParam", "/t", key) for key in ("/a", "/b")]
        for _ in range(100):
            if handler.budget.held >= 16 * MIB:
                break
            await asyncio.sleep(0.02)
        handler.budget.limit = handler.budget.held + BIG_REPLY  # full: nothing else fits
        with pytest.raises(Fault) as info:
            await client.call(master.uri, "getParam", "/t", "/c")
        assert info.value.code == FAULT_REPLY_BUDGET and "REPLY_BUDGET" in info.value.message
        assert (await client.call(master.uri, "getPid", "/t"))[2] == os.getpid()  # the master goes on
        await asyncio.sleep(1.5)  # more than REQUEST_TIMEOUT without reading
        for reader, _ in stalled:  # closed for not reading: the connection ends before the reply does
            data = await backports.wait_for(reader.read(), 5)
            assert len(data) < 16 * MIB
        await client.call(master.uri, "setParam", "/t", "/x", 1)  # a change drops the cached bodies
        await client.call(master.uri, "getPid", "/t")
        assert handler.budget.held == 0
        code, _, value = await client.call(master.uri, "getParam", "/t", "/c")
        assert code == 1 and value == "/c" * (8 * MIB)
        for _, writer in stalled:
            writer.close()
