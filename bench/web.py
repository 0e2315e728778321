"""Browser bridge benchmark: what mrosd's Foxglove WebSocket server forwards, against mrosd's own TCPROS.

Every party is a process of its own (so each one's CPU is its own): our master, one mrosd publisher sending flat
out, the bridge (``mros bridge``), and the consumers. For each payload (640x480 RGB, 1 MB and 8 MB Image, 1 MB
PointCloud2) and in the same run (``--link 20mbit``: the Wi-Fi lab instead, ``bench/web_link.py``):

- ``tcpros``: an mrosd subscriber (raw, AnyMsg) reading the topic directly: the reference;
- ``ws x1``: one WebSocket client (aiohttp) subscribed through the bridge;
- ``ceiling``: the same client reading one prebuilt messageData frame that a trivial aiohttp server resends
  in a loop: what this client can read at all on this machine, with no ROS behind it;
- ``ws x4``: four clients at once, with the publisher's own rate measured alongside (does it slow?);
- ``rb json``, ``rb cbor``, ``rb cbor-raw`` (640x480 and 1 MB images): one rosbridge client (aiohttp) on the
  bridge's rosbridge port with that ``compression`` (``none`` is JSON text with base64 data).

Printed first: the time rosbridge's JSON of a 640x480 image takes, and the ``png`` op of that JSON (which
the bridge compresses in a thread) with the event loop's longest stall meanwhile. Printed per row:
messages/s and MB/s (of ROS message bytes) reaching each client, the bridge's CPU seconds per forwarded MB (from
/proc), and the publisher's rate. Then the stalled-client test: one client subscribes to a 1 MB image
topic published at 30 Hz and never reads for ``--stall`` seconds (60 by default) while another keeps
reading; the bridge's RSS growth and the live client's rate are printed.

Usage: ``python -m bench.web [--seconds 5] [--stall 60] [--quick]``; each process is this module (``--role``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import socket
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from mrosd import backports

ROOT = Path(__file__).resolve().parent.parent
MB = 1e6
#: What the publisher offers in the throughput rows (bytes/s): above what any consumer here can take, so the
#: rows measure the consumer's path, without a publisher that busy-loops on a 2-core machine.
OFFERED_BYTES_PER_S = 1.5e9

#: rosbridge compressions measured per payload (the label's "json" is compression "none")
ROSBRIDGE_ROWS = {"rb json": "none", "rb cbor": "cbor", "rb cbor-raw": "cbor-raw"}
#: payloads that get rosbridge rows (rosbridge clients are browsers: camera images, not 8 MB frames)
ROSBRIDGE_PAYLOADS = ("image 640x480 rgb8", "image 1 MB")

#: (name, type, payload bytes)
PAYLOADS = [
    ("image 640x480 rgb8", "sensor_msgs/Image", 640 * 480 * 3),
    ("image 1 MB", "sensor_msgs/Image", 1024 * 1024),
    ("image 8 MB", "sensor_msgs/Image", 8 * 1024 * 1024),
    ("pointcloud2 1 MB", "sensor_msgs/PointCloud2", 1024 * 1024),
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def proc_cpu(pid: int) -> float:
    """utime + stime of ``pid`` in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def make_message(msg_type: str, size: int) -> Any:
    from mrosd.msg import get_message_class

    cls = get_message_class(msg_type)
    payload = bytes(range(256)) * (size // 256) + bytes(size % 256)
    if msg_type == "sensor_msgs/Image":
        width = 640 if size == 640 * 480 * 3 else size // 4 // 512
        height = size // (width * (3 if size == 640 * 480 * 3 else 4))
        enc = "rgb8" if size == 640 * 480 * 3 else "rgba8"
        return cls(height=height, width=width, encoding=enc, step=size // height, data=payload)
    return cls(height=1, width=size // 16, point_step=16, row_step=size, data=payload, is_dense=True)


# --- roles (each runs in its own process) -------------------------------------------------------------


async def role_pub(args: argparse.Namespace) -> None:
    import mrosd
    from mrosd.msg import get_message_class

    msg = make_message(args.type, args.size)
    counter = Path(args.counter)
    interval = 1.0 / args.rate if args.rate else 0.0
    async with mrosd.Node("bench_pub", master_uri=args.master, argv=[], host="127.0.0.1") as node:
        pub = await node.advertise(args.topic, get_message_class(args.type), queue_size=2)
        print("up", flush=True)
        last_write = time.monotonic()
        next_at = time.monotonic()
        while True:
            pub.publish_nowait(msg)
            now = time.monotonic()
            if now - last_write > 0.2:
                counter.write_text(f"{pub.messages_published} {now}")  # noqa: ASYNC240 - a few bytes, 5 times a second
                last_write = now
            if interval:
                next_at += interval
                await asyncio.sleep(max(0.0, next_at - time.monotonic()))
            else:
                await asyncio.sleep(0)


async def role_tcpros_sub(args: argparse.Namespace) -> None:
    import mrosd
    from mrosd.tcpros.subscriber import AnyMsg

    stats = {"msgs": 0, "bytes": 0, "first": 0.0}

    def on_msg(m: Any) -> None:
        if not stats["first"]:
            stats["first"] = time.monotonic()
        stats["msgs"] += 1
        stats["bytes"] += len(m.data)

    async with mrosd.Node("bench_sub", master_uri=args.master, argv=[], host="127.0.0.1") as node:
        await node.subscribe(args.topic, AnyMsg, callback=on_msg)
        await _measure(stats, args.seconds)


async def _measure(stats: dict[str, Any], seconds: float) -> None:
    async with backports.timeout(30):
        while not stats["first"]:  # noqa: ASYNC110 - set by the message callback
            await asyncio.sleep(0.01)
    start_msgs, start_bytes, start = stats["msgs"], stats["bytes"], time.monotonic()
    await asyncio.sleep(seconds)
    elapsed = time.monotonic() - start
    print(
        json.dumps({"msgs": stats["msgs"] - start_msgs, "bytes": stats["bytes"] - start_bytes, "seconds": elapsed}),
        flush=True,
    )


async def role_ws_sub(args: argparse.Namespace) -> None:
    import aiohttp

    stats = {"msgs": 0, "bytes": 0, "first": 0.0}
    async with (
        aiohttp.ClientSession() as http,
        http.ws_connect(args.url, protocols=["foxglove.websocket.v1"], max_msg_size=0) as ws,
    ):
        if not args.raw:
            channel = None
            while channel is None:
                msg = json.loads((await ws.receive()).data)
                if msg["op"] == "advertise":
                    channel = next((c["id"] for c in msg["channels"] if c["topic"] == args.topic), None)
            await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channel}]}))
        if args.stalled:
            print("stalled", flush=True)
            await asyncio.sleep(args.seconds)
            return

        async def read() -> None:
            async for msg in ws:
                if msg.type == aiohttp.WSMsgType.BINARY:
                    if not stats["first"]:
                        stats["first"] = time.monotonic()
                    stats["msgs"] += 1
                    stats["bytes"] += len(msg.data) - 13

        reader = asyncio.create_task(read())
        await _measure(stats, args.seconds)
        reader.cancel()
        os._exit(0)  # measured; a close handshake with a server that keeps sending is not part of it


async def role_rb_sub(args: argparse.Namespace) -> None:
    """A rosbridge client subscribed with ``--compression``; counts publish ops as ROS message bytes."""
    import aiohttp

    body = len(make_message(args.type, args.size).serialize())
    stats = {"msgs": 0, "bytes": 0, "first": 0.0}
    async with aiohttp.ClientSession() as http, http.ws_connect(args.url, max_msg_size=0) as ws:
        op = {"op": "subscribe", "topic": args.topic, "type": args.type, "compression": args.compression}
        await ws.send_str(json.dumps(op))

        async def read() -> None:
            async for msg in ws:
                if msg.type == aiohttp.WSMsgType.TEXT and not msg.data.startswith('{"op":"publish"'):
                    continue  # a status
                if not stats["first"]:
                    stats["first"] = time.monotonic()
                stats["msgs"] += 1
                stats["bytes"] += body

        reader = asyncio.create_task(read())
        await _measure(stats, args.seconds)
        reader.cancel()
        os._exit(0)  # as role_ws_sub


async def role_ceiling_server(args: argparse.Namespace) -> None:
    """Resend one prebuilt messageData frame as fast as the client takes it."""
    from aiohttp import web

    from mrosd.web.foxglove import message_data

    frame = message_data(1, 0, make_message(args.type, args.size).serialize())

    async def handler(request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(protocols=["foxglove.websocket.v1"], compress=False)
        await ws.prepare(request)
        try:
            while not ws.closed:
                await ws.send_bytes(frame)
                await asyncio.sleep(0)  # let the loop see the client's close frame
        except (ConnectionError, RuntimeError):
            pass
        return ws

    app = web.Application()
    app.router.add_get("/", handler)
    runner = web.AppRunner(app, handle_signals=False, shutdown_timeout=1.0)
    await runner.setup()
    await web.TCPSite(runner, "127.0.0.1", args.port).start()
    print("up", flush=True)
    await asyncio.Event().wait()


# --- orchestration -------------------------------------------------------------------------------------


class Bench:
    def __init__(self, seconds: float, shm: bool) -> None:
        self.seconds = seconds
        self.procs: list[subprocess.Popen[bytes]] = []
        self.env = {**os.environ, "PYTHONPATH": f"{ROOT}:{ROOT / 'cli'}:{os.environ.get('PYTHONPATH', '')}"}
        self.env.pop("ROS_MASTER_URI", None)
        # TCPROS between every mrosd process unless --shm: the reference is mrosd's TCPROS subscriber, and the
        # bridge's own subscription then crosses the same kind of socket.
        self.env["MROSD_SHM"] = "1" if shm else "0"

    def start(self, *argv: str, stdout: int | None = subprocess.PIPE) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            [sys.executable, *argv], env=self.env, stdout=stdout, stderr=subprocess.DEVNULL, start_new_session=True
        )
        self.procs.append(proc)
        return proc

    def role(self, role: str, *argv: str) -> subprocess.Popen[bytes]:
        return self.start("-m", "bench.web", "--role", role, *argv)

    def publisher(
        self, master: str, topic: str, msg_type: str, size: int, rate: float, counter: Path
    ) -> subprocess.Popen[bytes]:
        """A ``pub`` role process publishing ``size``-byte messages at ``rate``, once it says it is up."""
        pub = self.role(
            "pub", "--master", master, "--topic", topic, "--type", msg_type, "--size", str(size),
            "--rate", str(rate), "--counter", str(counter),
        )  # fmt: skip
        assert pub.stdout is not None
        pub.stdout.readline()
        return pub

    def stop(self, proc: subprocess.Popen[bytes]) -> None:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()

    def close(self) -> None:
        for proc in reversed(self.procs):
            self.stop(proc)

    @staticmethod
    def result(proc: subprocess.Popen[bytes], timeout: float) -> dict[str, float]:
        out, _ = proc.communicate(timeout=timeout)
        lines = [ln for ln in out.decode().splitlines() if ln.startswith("{")]
        if not lines:
            return {"msgs": 0, "bytes": 0, "seconds": 1.0}
        data: dict[str, float] = json.loads(lines[-1])
        return data


def rate(r: dict[str, float]) -> tuple[float, float]:
    return r["msgs"] / r["seconds"], r["bytes"] / r["seconds"] / MB


def read_counter(path: Path) -> tuple[int, float]:
    try:
        count, stamp = path.read_text().split()
        return int(count), float(stamp)
    except (OSError, ValueError):
        return 0, time.monotonic()


def measure_phase(
    bench: Bench,
    args: argparse.Namespace,
    bridge: subprocess.Popen[bytes],
    counter: Path,
    rows: dict[str, Any],
    label: str,
    procs: list[subprocess.Popen[bytes]],
    bridge_cpu: bool,
) -> dict[str, float]:
    """Wait for the consumers' results; record them with the bridge's CPU per MB and the publisher's rate."""
    c0, p0 = proc_cpu(bridge.pid), read_counter(counter)
    results = [bench.result(p, args.seconds + 40) for p in procs]
    c1, p1 = proc_cpu(bridge.pid), read_counter(counter)
    pub_rate = (p1[0] - p0[0]) / max(p1[1] - p0[1], 1e-9)
    total_mb = sum(r["bytes"] for r in results) / MB
    cpu = (c1 - c0) / total_mb if bridge_cpu and total_mb else float("nan")
    rows[label] = (results, cpu, pub_rate)
    return results[0]


def encode_times() -> None:
    """rosbridge's JSON of a 640x480 RGB image (decode + JSON with base64 data), against rosbridge_suite#367;
    then the png op of that JSON, as the bridge makes it (off the loop), and the loop's longest stall."""
    import random
    import statistics

    from mrosd.msg import get_message_class
    from mrosd.web import rosbridge as rb

    cls = get_message_class("sensor_msgs/Image")
    body = make_message("sensor_msgs/Image", 640 * 480 * 3).serialize()
    times = []
    for _ in range(50):
        t0 = time.perf_counter()
        text = rb.publish_json("/camera/image", cls.deserialize(body))
        times.append(time.perf_counter() - t0)
    print(
        f"rosbridge JSON of a 640x480 rgb8 Image: median {statistics.median(times) * 1e3:.2f} ms, "
        f"max {max(times) * 1e3:.2f} ms ({len(text) / 1e6:.2f} MB of text; rosbridge_suite#367 measured 269 ms)",
        flush=True,
    )
    # Noise, as a camera's pixels are: the bench's byte pattern would compress to nothing in no time.
    noise = cls(height=480, width=640, encoding="rgb8", step=1920, data=random.Random(0).randbytes(640 * 480 * 3))
    noise_body = noise.serialize()
    png_ms, size, late = asyncio.run(_png_times(cls, noise_body))
    print(
        f"rosbridge png op of that JSON (camera noise, {size / 1e6:.2f} MB op): median {png_ms:.1f} ms in the bridge's "
        "png threads; a 1 ms timer on the event loop late by (99th percentile / worst, ms): "
        + ", ".join(f"{name} {p99:.1f} / {worst:.1f}" for name, (p99, worst) in late.items()),
        flush=True,
    )


async def _png_times(cls: Any, body: bytes) -> tuple[float, int, dict[str, tuple[float, float]]]:
    """The bridge's png op of ``body``'s JSON: median time over 20, the op's size, and how late a 1 ms timer
    on the loop fires while they run, beside the same timer idle and beside 20 JSON encodes on the loop."""
    import statistics

    from mrosd.web import rosbridge as rb
    from mrosd.web.rosbridge_server import png_op_off_loop

    text = rb.publish_json("/camera/image", cls.deserialize(body))
    times: list[float] = []
    size = 0

    async def idle() -> None:
        await asyncio.sleep(0.8)

    async def json_path() -> None:
        for _ in range(20):
            rb.publish_json("/camera/image", cls.deserialize(body))
            await asyncio.sleep(0.04)

    async def png() -> None:
        nonlocal size
        for _ in range(20):
            t0 = time.perf_counter()
            size = len(await png_op_off_loop(text))
            times.append(time.perf_counter() - t0)

    late = {name: await _timer_lateness(work) for name, work in (("idle", idle), ("json", json_path), ("png", png))}
    return statistics.median(times) * 1e3, size, late


async def _timer_lateness(work: Callable[[], Awaitable[None]]) -> tuple[float, float]:
    """How late (ms) a 1 ms timer on the event loop fires while ``work`` runs: 99th percentile and worst (on a
    shared machine the worst is often another process's doing, hence both, and the idle loop beside them)."""
    late: list[float] = []
    stop = asyncio.Event()

    async def timer() -> None:
        while not stop.is_set():
            t0 = time.perf_counter()
            await asyncio.sleep(0.001)
            late.append((time.perf_counter() - t0 - 0.001) * 1e3)

    ticking = asyncio.create_task(timer())
    await work()
    stop.set()
    await ticking
    late.sort()
    return late[int(len(late) * 0.99)], late[-1]


def run(args: argparse.Namespace) -> int:
    encode_times()
    bench = Bench(args.seconds, args.shm)
    print(f"transport between mrosd processes: {'shared memory when offered' if args.shm else 'TCPROS'}")
    port = free_port()
    master = f"http://127.0.0.1:{port}/"
    tmp = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench-web-{os.getpid()}"
    tmp.mkdir(exist_ok=True)
    try:
        bench.start("-m", "mrosd.master", "--port", str(port), stdout=subprocess.DEVNULL)
        _wait_port(port)
        ws_port, rb_port = free_port(), free_port()
        bridge = bench.start(
            *("-m", "mros_cli.main", "--master-uri", master, "bridge"),
            *("--port", str(ws_port), "--rosbridge-port", str(rb_port)),
            stdout=subprocess.DEVNULL,
        )
        _wait_port(ws_port)
        _wait_port(rb_port)
        url = f"ws://127.0.0.1:{ws_port}/"
        rb_url = f"ws://127.0.0.1:{rb_port}/"
        head = f"{'payload':22} {'consumer':11} {'msg/s':>8} {'MB/s':>8} {'vs tcpros':>9}"
        print(f"{head} {'bridge CPU s/MB':>15} {'pub msg/s':>9}")
        payloads = PAYLOADS[1:3] if args.quick else PAYLOADS
        for name, msg_type, size in payloads:
            topic = "/bench_" + re.sub(r"\W+", "_", name)
            counter = tmp / f"{topic[1:]}.count"
            offered = min(500.0, OFFERED_BYTES_PER_S / size)  # more than any consumer here takes
            pub = bench.publisher(master, topic, msg_type, size, offered, counter)
            rows: dict[str, Any] = {}

            ref = measure_phase(
                bench,
                args,
                bridge,
                counter,
                rows,
                "tcpros",
                [bench.role("tcpros-sub", "--master", master, "--topic", topic, "--seconds", str(args.seconds))],
                False,
            )
            measure_phase(
                bench,
                args,
                bridge,
                counter,
                rows,
                "ws x1",
                [bench.role("ws-sub", "--url", url, "--topic", topic, "--seconds", str(args.seconds))],
                True,
            )
            cport = free_port()
            server = bench.role("ceiling-server", "--port", str(cport), "--type", msg_type, "--size", str(size))
            assert server.stdout is not None
            server.stdout.readline()
            measure_phase(
                bench,
                args,
                bridge,
                counter,
                rows,
                "ceiling",
                [bench.role("ws-sub", "--url", f"ws://127.0.0.1:{cport}/", "--raw", "--seconds", str(args.seconds))],
                False,
            )
            bench.stop(server)
            measure_phase(
                bench,
                args,
                bridge,
                counter,
                rows,
                "ws x4",
                [
                    bench.role("ws-sub", "--url", url, "--topic", topic, "--seconds", str(args.seconds))
                    for _ in range(4)
                ],
                True,
            )
            for label, compression in ROSBRIDGE_ROWS.items() if name in ROSBRIDGE_PAYLOADS else ():
                rb_sub = bench.role(
                    *("rb-sub", "--url", rb_url, "--topic", topic, "--type", msg_type, "--size", str(size)),
                    *("--compression", compression, "--seconds", str(args.seconds)),
                )
                measure_phase(bench, args, bridge, counter, rows, label, [rb_sub], True)
            ref_mb = rate(ref)[1]
            for label, (results, cpu, pub_rate) in rows.items():
                for i, r in enumerate(results):
                    msgs, mbs = rate(r)
                    tag = label if len(results) == 1 else f"{label}#{i + 1}"
                    ratio = mbs / ref_mb if ref_mb else float("nan")
                    print(
                        f"{name:22} {tag:11} {msgs:8.1f} {mbs:8.1f} {ratio:9.2f} {cpu:15.4f} {pub_rate:9.1f}",
                        flush=True,
                    )
            bench.stop(pub)
        stall(bench, args, master, url, bridge, tmp)
    finally:
        bench.close()
    return 0


def stall(
    bench: Bench, args: argparse.Namespace, master: str, url: str, bridge: subprocess.Popen[bytes], tmp: Path
) -> None:
    topic = "/bench_stall"
    counter = tmp / "stall.count"
    pub = bench.publisher(master, topic, "sensor_msgs/Image", 1024 * 1024, 30.0, counter)
    time.sleep(1.0)
    rss0 = proc_rss(bridge.pid)
    stalled = bench.role("ws-sub", "--url", url, "--topic", topic, "--stalled", "--seconds", str(args.stall))
    assert stalled.stdout is not None
    stalled.stdout.readline()
    live = bench.role("ws-sub", "--url", url, "--topic", topic, "--seconds", str(args.stall - 2))
    peak = rss0
    deadline = time.monotonic() + args.stall
    while time.monotonic() < deadline and stalled.poll() is None:
        peak = max(peak, proc_rss(bridge.pid))
        time.sleep(0.5)
    r = bench.result(live, 60)
    msgs, mbs = rate(r)
    print(
        f"stalled client for {args.stall:.0f} s at 30 x 1 MB/s: bridge RSS {rss0 / 2**20:.1f} -> peak "
        f"{peak / 2**20:.1f} MiB (+{(peak - rss0) / 2**20:.1f} MiB); the other client read {msgs:.1f} msg/s "
        f"({mbs:.1f} MB/s)",
        flush=True,
    )
    bench.stop(stalled)
    bench.stop(pub)


def _wait_port(port: int, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listens on {port}")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.web", description=__doc__.split("\n\n")[0])
    parser.add_argument("--role", default="")
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--stall", type=float, default=60.0)
    parser.add_argument("--quick", action="store_true", help="1 MB and 8 MB images only, 10 s stall")
    parser.add_argument("--shm", action="store_true", help="let mrosd processes use shared memory (default TCPROS)")
    parser.add_argument("--master", default="")
    parser.add_argument("--topic", default="")
    parser.add_argument("--type", default="sensor_msgs/Image")
    parser.add_argument("--size", type=int, default=0)
    parser.add_argument("--rate", type=float, default=0.0)
    parser.add_argument("--counter", default="")
    parser.add_argument("--url", default="")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--raw", action="store_true")
    parser.add_argument("--stalled", action="store_true", help="(ws-sub) subscribe, then never read")
    parser.add_argument("--compression", default="none", help="(rb-sub) rosbridge compression")
    parser.add_argument("--link", default="", help="the Wi-Fi lab behind a link of this rate: bench/web_link.py")
    args = parser.parse_args(argv)
    if args.link:
        return int(__import__("bench.web_link", fromlist=["run"]).run(args.link))
    roles = {
        "pub": role_pub,
        "tcpros-sub": role_tcpros_sub,
        "ws-sub": role_ws_sub,
        "rb-sub": role_rb_sub,
        "ceiling-server": role_ceiling_server,
    }
    if args.role:
        from mrosd.loop import run as run_loop

        try:
            run_loop(roles[args.role](args))
        except KeyboardInterrupt:
            pass
        return 0
    if args.quick:
        args.stall = min(args.stall, 10.0)
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
