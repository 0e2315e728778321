"""Load: the short soak (daemon + many real nodes, bounded RSS/fds, no IXM segment left held), a stalled subscriber."""

from __future__ import annotations

import asyncio
import socket
import struct
import subprocess
import sys
from pathlib import Path

import mrosd
from mrosd.msg import get_message_class
from tests.reliability.relnodes import start_master
from tests.rosenv import PROJECT_ROOT, Processes

String = get_message_class("std_msgs/String")


def rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def test_a_short_soak_of_the_daemon_and_many_nodes_keeps_memory_fds_and_shm_bounded() -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench.soak",
            "--seconds",
            "15",
            "--interval",
            "4",
            "--nodes",
            "30",
            "--topics",
            "300",
            "--fanout",
            "10",
            "--workers",
            "2",
            "--hot-rate",
            "50",
        ],
        cwd=PROJECT_ROOT,
        capture_output=True,
        timeout=150,
        check=False,
    )
    out = done.stdout.decode()
    assert done.returncode == 0, out + done.stderr.decode()[-3000:]
    assert "stalled raw subscriber of /hot: connected" in out
    assert out.rstrip().endswith("PASS")


async def test_a_stalled_subscriber_cannot_grow_the_publishers_memory(procs: Processes) -> None:
    _, uri = start_master(procs)
    async with mrosd.Node("big_talker", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        pub = await node.advertise("/big", String, queue_size=5)
        # a subscriber that completes the handshake and then never reads a byte
        loop = asyncio.get_running_loop()
        stalled = socket.socket()
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.setblocking(False)
        await loop.sock_connect(stalled, ("127.0.0.1", node.tcpros_port))
        fields = [b"callerid=/stalled", b"topic=/big", b"md5sum=*", b"type=std_msgs/String", b"tcp_nodelay=0"]
        body = b"".join(struct.pack("<I", len(f)) + f for f in fields)
        await loop.sock_sendall(stalled, struct.pack("<I", len(body)) + body)
        try:
            for _ in range(100):
                if pub.get_num_connections() >= 1:
                    break
                await asyncio.sleep(0.02)
            assert pub.get_num_connections() == 1
            payload = String(data="x" * (1 << 20))
            await pub.publish(payload)
            before = rss_mib()
            for _ in range(400):  # 400 MiB offered to a reader that takes nothing
                await pub.publish(payload)
                await asyncio.sleep(0)
            grown = rss_mib() - before
            assert grown < 100, f"publisher grew by {grown:.0f} MiB for a stalled subscriber"
        finally:
            stalled.close()
