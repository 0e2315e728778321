"""Attacker and victim programs for the connection-flood tests, run as real processes.

``FLOOD`` is the attacker: plain sockets, no mrosd, its own descriptor limit raised to the hard one so the test
process's limit does not bound the flood. ``FLOOD_TALKER`` is the victim: an mrosd node publishing at 100 Hz
with the descriptor limit and event loop (``MROSD_LOOP``) the test gives it, logging WARNING and up to stderr.
"""

from __future__ import annotations

import http.client
import json
import os
import subprocess
import sys
import time
import urllib.parse
import xmlrpc.client
from pathlib import Path
from typing import Any

from tests.rosenv import Processes

#: argv: port count payload_hex seconds reconnect(0/1). Opens ``count`` connections (all at once, non-blocking),
#: sends ``payload`` on each and holds them; with reconnect, a connection the target closes is opened again at
#: once. Prints ``connected <n>`` once the first round is connected (or 30 s passed), then one JSON line of
#: counts when ``seconds`` are up.
FLOOD = r"""
import errno, json, resource, selectors, socket, sys, time
port, count, payload, seconds, reconnect = (
    int(sys.argv[1]), int(sys.argv[2]), bytes.fromhex(sys.argv[3]), float(sys.argv[4]), sys.argv[5] == "1")
_, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
sel = selectors.DefaultSelector()
stats = {"opened": 0, "failed": 0, "dropped": 0}
connecting = 0
def open_one():
    # non-blocking: one connect waiting for the target's accept queue must not hold up the others
    global connecting
    s = socket.socket()
    s.setblocking(False)
    err = s.connect_ex(("127.0.0.1", port))
    if err not in (0, errno.EINPROGRESS):
        s.close()
        stats["failed"] += 1
        return
    sel.register(s, selectors.EVENT_WRITE, "connecting")
    connecting += 1
def connected(s):
    global connecting
    connecting -= 1
    if s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) != 0:
        sel.unregister(s)
        s.close()
        stats["failed"] += 1
        return
    try:
        if payload:
            s.send(payload)
    except OSError:
        pass
    sel.modify(s, selectors.EVENT_READ, "open")
    stats["opened"] += 1
def lost(s):
    sel.unregister(s)
    s.close()
    stats["dropped"] += 1
    if reconnect:
        open_one()
def turn(timeout):
    for key, _ in sel.select(timeout):
        s = key.fileobj
        if key.data == "connecting":
            connected(s)
            continue
        try:
            data = s.recv(65536)
        except OSError:
            data = b""
        if not data:
            lost(s)
for _ in range(count):
    open_one()
first = time.monotonic() + 30.0
while connecting and time.monotonic() < first:
    turn(0.1)
print("connected", stats["opened"], flush=True)
deadline = time.monotonic() + seconds
while time.monotonic() < deadline:
    turn(0.1)
stats["held"] = sum(1 for key in sel.get_map().values() if key.data == "open")
print(json.dumps(stats), flush=True)
"""

#: argv: topic nofile. Publishes std_msgs/String on ``topic`` at 100 Hz under RLIMIT_NOFILE ``nofile`` (0: as
#: inherited), on ``mrosd.loop.run`` (so ``MROSD_LOOP`` picks the loop); prints ``ready <tcpros port>``.
FLOOD_TALKER = r"""
import asyncio, logging, resource, sys
import mrosd
from mrosd.loop import run
from mrosd.msg import get_message_class
String = get_message_class("std_msgs/String")
logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(levelname)s %(name)s: %(message)s")
nofile = int(sys.argv[2])
if nofile:
    resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
async def main():
    async with mrosd.Node("flood_talker", host="127.0.0.1", argv=[], rosout=False) as node:
        pub = await node.advertise(sys.argv[1], String)
        print("ready", node.tcpros_port, type(asyncio.get_running_loop()).__module__, flush=True)
        n = 0
        while True:
            await pub.publish(String(data=str(n)))
            n += 1
            await asyncio.sleep(0.01)
run(main())
"""


def start_talker(
    procs: Processes, env: dict[str, str], tmp: Path, topic: str, *, nofile: int = 0, loop: str = "asyncio"
) -> tuple[subprocess.Popen[bytes], int, Path]:
    """Start FLOOD_TALKER; return the process, its TCPROS port and the file its log goes to."""
    log_path = tmp / f"talker-{loop}-{time.monotonic_ns()}.log"
    env = {**env, "MROSD_LOOP": loop}
    with open(log_path, "wb") as log:
        proc = procs.start([sys.executable, "-c", FLOOD_TALKER, topic, str(nofile)], env, stderr=log.fileno())
    assert proc.stdout is not None
    line = proc.stdout.readline().decode().split()
    assert line[:1] == ["ready"], log_path.read_text()[-3000:]
    assert ("uvloop" in line[2]) == (loop == "uvloop"), line
    return proc, int(line[1]), log_path


def start_flood(
    procs: Processes, port: int, count: int, payload: bytes, seconds: float, *, reconnect: bool = False
) -> subprocess.Popen[bytes]:
    """Start FLOOD and wait (bounded) until its first round of connections is open."""
    proc = procs.start(
        [sys.executable, "-c", FLOOD, str(port), str(count), payload.hex(), str(seconds), "1" if reconnect else "0"],
        dict(os.environ),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().decode().split()
    assert line[:1] == ["connected"], line
    return proc


def flood_result(proc: subprocess.Popen[bytes], timeout: float) -> dict[str, Any]:
    """FLOOD's final counts (waits at most ``timeout`` seconds for it to finish)."""
    assert proc.stdout is not None
    out, _ = proc.communicate(timeout=timeout)
    result: dict[str, Any] = json.loads(out.decode().strip().splitlines()[-1])
    return result


def get_pid(uri: str, timeout: float) -> tuple[int, float]:
    """getPid on a fresh connection: (its code, or -9 when it failed; seconds taken), bounded by ``timeout``."""
    started = time.monotonic()
    parsed = urllib.parse.urlsplit(uri)
    conn = http.client.HTTPConnection(parsed.hostname or "", parsed.port, timeout=timeout)
    try:
        conn.request("POST", "/", xmlrpc.client.dumps(("/probe",), "getPid"), {"Content-Type": "text/xml"})
        reply = conn.getresponse()
        code = xmlrpc.client.loads(reply.read())[0][0][0] if reply.status == 200 else -reply.status
    except (OSError, xmlrpc.client.Error):
        code = -9
    finally:
        conn.close()
    return int(code), time.monotonic() - started
