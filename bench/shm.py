"""Shared-memory topic transport against plain TCPROS: 1 MB and 8 MB messages, one and four subscriber processes.

For each size, subscriber count and transport, one publisher process sends ``count`` messages back to back
(each a prebuilt body: serialization is the same for both transports and not measured) to 1 or 4 subscriber
processes, with queues deep enough that nothing is dropped. Reported: per-subscriber throughput (the
message bytes one subscriber received, over the time from the first publish to the last subscriber's last
message, CLOCK_MONOTONIC being shared by all processes), and the publisher's CPU time per message
(``process_time`` from the first publish until every subscriber is done, so TCPROS's deferred socket writes
are counted). Shared memory: ``mrosd.shm`` endpoints (copy-out subscribers). TCPROS: ``mrosd.Node``
publisher and ``AnyMsg`` subscribers through an mrosd master started for the run. Rounds interleave the
transports; the median is printed.

Usage: ``python -m bench.shm [--rounds 3] [--sizes 1,8] [--subs 1,4] [--transports shm,tcpros]``.

``--latency``: one-way latency instead, from the publish call to the subscriber's callback (both processes
read CLOCK_MONOTONIC; the publisher writes its clock into the message's first 8 bytes), median and p99 over
``--count`` messages 20 ms apart (no queueing), for 1 KB, 64 KB, 1 MB, 8 MB and 64 MB messages
(``--lat-sizes``; messages over 8 MB go ``LAT_GAP_HUGE`` apart, at most ``LAT_COUNT_HUGE`` of them: a copied
64 MB message takes longer than 20 ms, and queueing is not latency),
per mode (``--modes``): ``copy`` (today's shared-memory path: serialized into the ring, copied out),
``pool`` (the same, with ``max_message_size`` declared: the ring made and faulted in before the subscriber
attaches), ``loan`` (``mrosd.Node`` publisher loans, ``zero_copy`` subscriber views: nothing copied),
``tcpros`` (``mrosd.Node`` over TCPROS), ``roscpp`` (``bench/shm_roscpp.cpp``, compiled for the run).
The first message on a new connection (published as
soon as the subscriber is attached) is reported separately.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import select
import shutil
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from mrosd import backports

COUNTS = {1: 30, 8: 10}  # messages per run, by size in MB
#: Messages sent before the measurement, for both transports: the shared-memory ring grows, and every one of its
#: slots (a ring of 1 MB messages has 3) gets its pages, outside the measured run (fresh shared memory costs
#: ~0.7 ms per MB to touch the first time here; docs/shm.md).
WARMUP = 4
TOPIC = "/bench_shm"


# --- the publisher and subscriber processes --------------------------------------------------------------


def _say(*parts: object) -> None:
    print(*parts, flush=True)


async def _stdin_line() -> bytes:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    return await reader.readline()


async def _image_pool_publisher(name: str, master: str, queue_size: int, max_size: int) -> tuple[Any, Any]:
    """A started node and its sensor_msgs/Image publisher with a pool of ``max_size`` slots (for loans)."""
    from mrosd import Node
    from mrosd.msg import get_message_class

    node = Node(name, master_uri=master, argv=[], rosout=False, logger_services=False)
    await node.start()
    pub = await node.advertise(
        TOPIC, get_message_class("sensor_msgs/Image"), queue_size=queue_size, max_message_size=max_size
    )
    return node, pub


async def _pub(args: argparse.Namespace) -> None:
    body = os.urandom(args.size)
    subs = int(args.subs)
    changed = asyncio.Event()
    if args.transport == "loan":
        node, lpub = await _image_pool_publisher("bench_pub", args.master, args.count + WARMUP, args.size)
        _say("ready")
        await lpub.wait_for_subscribers(subs, timeout=30)
        await asyncio.sleep(0.3)

        def loaned(_body: Any) -> None:
            endpoint = lpub.shm.endpoint if lpub.shm is not None else None
            while endpoint is not None and not endpoint.can_lend(args.size - 64):
                time.sleep(0.0002)  # every slot busy: a camera would wait for its next frame
            msg = lpub.loan(data=args.size - 64)
            msg.data[:8] = body[:8]  # the application writes its frame into the pool (not measured here)
            lpub.publish_nowait(msg)

        publish: Any = loaned
        for _ in range(WARMUP):
            publish(body)
        closer: Any = node.aclose
    elif args.transport == "shm":
        from mrosd.shm import ShmPublisherEndpoint

        ep = ShmPublisherEndpoint(TOPIC, queue_size=args.count, on_change=changed.set, max_ring_bytes=1 << 30)
        await ep.start()
        _say("addr", ep.address, ep.token)
        while len(ep.links) < subs:
            changed.clear()
            await changed.wait()
        for _ in range(WARMUP):
            ep.publish(body)
        publish = ep.publish
        closer = ep.aclose
    else:
        from mrosd import Node
        from mrosd.msg import get_message_class

        node = Node("bench_pub", master_uri=args.master, argv=[], rosout=False, logger_services=False)
        await node.start()
        pub = await node.advertise(TOPIC, get_message_class("std_msgs/UInt8MultiArray"), queue_size=args.count + WARMUP)
        _say("ready")
        await pub.wait_for_subscribers(subs, timeout=30)
        for _ in range(WARMUP):
            pub.publish_serialized(body)
        publish = pub.publish_serialized
        closer = node.aclose
    line = asyncio.ensure_future(_stdin_line())
    _say("attached")
    await asyncio.sleep(0.5)  # the warm-up messages are taken by every subscriber
    cpu0, t0 = time.process_time(), time.monotonic()
    for _ in range(args.count):
        publish(body)
        await asyncio.sleep(args.pace_ms / 1e3)
    await line  # the bench says every subscriber is done
    _say("pub", json.dumps({"t0": t0, "cpu": (time.process_time() - cpu0) / args.count}))
    await closer()


async def _sub(args: argparse.Namespace) -> None:
    got = 0
    last = 0.0
    done = asyncio.Event()
    total = args.count + WARMUP  # the warm-up messages, then the measured ones

    def on_body(body: Any) -> None:
        nonlocal got, last
        got += 1
        last = time.monotonic()
        if got >= total:
            done.set()

    if args.transport == "loan":
        from mrosd import Node
        from mrosd.msg import get_message_class

        def on_msg(msg: Any) -> None:
            msg.release()  # a view: nothing copied; the lease ends at once
            on_body(msg)

        node = Node(f"bench_sub{os.getpid()}", master_uri=args.master, argv=[], rosout=False, logger_services=False)
        await node.start()
        sub = await node.subscribe(
            TOPIC,
            get_message_class("sensor_msgs/Image"),
            on_msg,
            queue_size=args.count + WARMUP,
            zero_copy=True,
            max_leased=1,
        )
        await backports.wait_for(done.wait(), 120)
        dropped = sum(row[3] for row in sub.stats()[1])
        await node.aclose()
    elif args.transport == "shm":
        from mrosd.shm import ShmSubscriberConnection, parse_answer
        from mrosd.shm.negotiate import PROTOCOL, VERSION
        from mrosd.wire.header import ConnectionHeader

        answer = parse_answer([PROTOCOL, VERSION, args.address, args.token])
        assert answer is not None
        header = ConnectionHeader(callerid=f"/bench_sub{os.getpid()}", topic=TOPIC, md5sum="*", type="*")
        conn = await ShmSubscriberConnection.attach(answer, header, on_frame=on_body)
        await backports.wait_for(done.wait(), 120)
        dropped = conn.dropped
        await conn.aclose()
    else:
        from mrosd import Node
        from mrosd.tcpros.subscriber import AnyMsg

        node = Node(f"bench_sub{os.getpid()}", master_uri=args.master, argv=[], rosout=False, logger_services=False)
        await node.start()
        await node.subscribe(TOPIC, AnyMsg, on_body, queue_size=args.count + WARMUP)
        await backports.wait_for(done.wait(), 120)
        dropped = 0
        await node.aclose()
    _say("sub", json.dumps({"last": last, "got": got, "dropped": dropped}))


# --- latency ---------------------------------------------------------------------------------------------

_STAMP = struct.Struct("=d")
LAT_GAP = 0.02
LAT_GAP_HUGE = 0.25
LAT_COUNT_HUGE = 20


def _lat_gap(size: int) -> float:
    return LAT_GAP if size <= 8 << 20 else LAT_GAP_HUGE


async def _lat_pub(args: argparse.Namespace) -> None:
    body = bytearray(args.size)
    changed = asyncio.Event()
    if args.mode == "loan":
        node, pub = await _image_pool_publisher("bench_lat_pub", args.master, 4, args.size + 4096)
        _say("addr", "-", "-")
        await pub.wait_for_subscribers(1, timeout=30)
        await asyncio.sleep(0.2)  # the subscriber's side of the attachment completes

        def loaned(_body: Any) -> None:
            msg = pub.loan(data=args.size)
            _STAMP.pack_into(msg.data, 0, time.monotonic())  # stamped at the publish call, into the pool
            msg.encoding = "mono8"
            pub.publish_nowait(msg)

        publish: Any = loaned
        closer: Any = node.aclose
    elif args.mode in ("copy", "pool"):
        from mrosd.shm import ShmPublisherEndpoint

        declared = args.size if args.mode == "pool" else None
        ep = ShmPublisherEndpoint(TOPIC, queue_size=4, on_change=changed.set, max_message_size=declared)
        await ep.start()
        _say("addr", ep.address, ep.token)
        while not ep.links:
            changed.clear()
            await changed.wait()
        publish = ep.publish
        closer = ep.aclose
    else:
        from mrosd import Node
        from mrosd.msg import get_message_class

        node = Node("bench_lat_pub", master_uri=args.master, argv=[], rosout=False, logger_services=False)
        await node.start()
        pub = await node.advertise(TOPIC, get_message_class("std_msgs/UInt8MultiArray"), queue_size=4)
        _say("addr", "-", "-")
        await pub.wait_for_subscribers(1, timeout=30)
        publish = pub.publish_serialized
        closer = node.aclose
    for i in range(args.count + 1):  # the first one as the subscriber is attached, then one every gap
        _STAMP.pack_into(body, 0, time.monotonic())
        publish(body)
        await asyncio.sleep(0.2 if i == 0 else _lat_gap(args.size))
    await _stdin_line()
    await closer()


async def _lat_sub(args: argparse.Namespace) -> None:
    lat: list[float] = []
    done = asyncio.Event()
    #: (process CPU, wall) when the second message arrived: the subscriber's CPU share while messages flow
    cpu_from: list[float] = []

    def on_body(body: Any) -> None:
        lat.append(time.monotonic() - _STAMP.unpack_from(body, 0)[0])
        if len(lat) == 2:
            cpu_from[:] = [time.process_time(), time.monotonic()]
        if len(lat) > args.count:
            done.set()

    if args.mode == "loan":
        from mrosd import Node
        from mrosd.msg import get_message_class

        def on_view(msg: Any) -> None:
            with msg:
                on_body(msg.data)

        node = Node(f"bench_sub{os.getpid()}", master_uri=args.master, argv=[], rosout=False, logger_services=False)
        await node.start()
        image = get_message_class("sensor_msgs/Image")
        await node.subscribe(TOPIC, image, on_view, queue_size=4, zero_copy=True, max_leased=1)
        await backports.wait_for(done.wait(), 120)
        await node.aclose()
    elif args.mode in ("copy", "pool"):
        from mrosd.shm import ShmSubscriberConnection, parse_answer
        from mrosd.shm.negotiate import PROTOCOL, VERSION
        from mrosd.wire.header import ConnectionHeader

        answer = parse_answer([PROTOCOL, VERSION, args.address, args.token])
        assert answer is not None
        header = ConnectionHeader(callerid=f"/bench_sub{os.getpid()}", topic=TOPIC, md5sum="*", type="*")
        conn = await ShmSubscriberConnection.attach(answer, header, on_frame=on_body)
        await backports.wait_for(done.wait(), 120)
        await conn.aclose()
    else:
        from mrosd import Node
        from mrosd.tcpros.subscriber import AnyMsg

        node = Node(f"bench_sub{os.getpid()}", master_uri=args.master, argv=[], rosout=False, logger_services=False)
        await node.start()
        await node.subscribe(TOPIC, AnyMsg, lambda raw: on_body(raw.data), queue_size=4)
        await backports.wait_for(done.wait(), 120)
        await node.aclose()
    cpu, wall = time.process_time() - cpu_from[0], time.monotonic() - cpu_from[1]
    _say("lat", json.dumps({"lat": lat, "cpu": cpu / wall}))


def _compile_roscpp(tmp: Path) -> str | None:
    """The roscpp partner (``bench/shm_roscpp.cpp``), built once per run; None without g++ or roscpp."""
    if shutil.which("g++") is None:
        return None
    flags = subprocess.run(
        ["pkg-config", "--cflags", "--libs", "roscpp", "sensor_msgs"], capture_output=True, text=True, check=False
    )
    if flags.returncode != 0:
        return None
    out = tmp / "shm_roscpp"
    source = Path(__file__).with_name("shm_roscpp.cpp")
    build = subprocess.run(
        ["g++", "-O2", "-o", str(out), str(source), *flags.stdout.split()], capture_output=True, check=False
    )
    return str(out) if build.returncode == 0 else None


def _cpp(binary: str, master: str, *argv: str) -> subprocess.Popen[bytes]:
    env = {**os.environ, "ROS_MASTER_URI": master, "ROS_HOSTNAME": "127.0.0.1"}
    return subprocess.Popen(
        [binary, *argv], stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True, env=env
    )


def _lat_one(mode: str, size: int, count: int, master: str, cpp: str | None = None) -> tuple[list[float], float]:
    """One row's latencies (s) and the subscriber's CPU share while they flowed (nan for roscpp's)."""
    if size > 8 << 20:
        count = min(count, LAT_COUNT_HUGE)
    common = ["--mode", mode, "--size", str(size), "--count", str(count), "--master", master]
    procs: list[subprocess.Popen[bytes]] = []
    try:
        if mode == "roscpp":
            assert cpp is not None
            pub = _cpp(cpp, master, "pub", str(size), str(count), str(_lat_gap(size)))
            procs.append(pub)
            _line(pub, "addr")
            sub = _cpp(cpp, master, "sub", str(count))
        else:
            pub = _spawn("--role", "lpub", *common)
            procs.append(pub)
            address, token = _line(pub, "addr").split()
            sub = _spawn("--role", "lsub", *common, "--address", address, "--token", token)
        procs.append(sub)
        got = json.loads(_line(sub, "lat"))
        lat, cpu = (got, float("nan")) if isinstance(got, list) else (got["lat"], got["cpu"])
        assert pub.stdin is not None
        pub.stdin.write(b"done\n")
        pub.stdin.flush()
        return lat, cpu
    finally:
        _reap(procs)


def _latency(args: argparse.Namespace, master: str) -> int:
    sizes = [int(s) for s in args.lat_sizes.split(",")]
    modes = args.modes.split(",")
    with tempfile.TemporaryDirectory(prefix="bench-shm-") as tmp:
        cpp = _compile_roscpp(Path(tmp)) if "roscpp" in modes else None
        return _latency_rows(args, master, sizes, modes, cpp)


def _latency_rows(args: argparse.Namespace, master: str, sizes: list[int], modes: list[str], cpp: str | None) -> int:
    if "roscpp" in modes and cpp is None:
        print("roscpp: cannot compile bench/shm_roscpp.cpp (g++ or the roscpp headers missing); skipped")
        modes.remove("roscpp")
    print(f"{'size':>6} {'mode':>7} {'median us':>10} {'p99 us':>9} {'first us':>9} {'sub CPU':>8}")
    table: dict[tuple[int, str], tuple[float, float, float]] = {}
    for size in sizes:
        for mode in modes:
            lat, cpu = _lat_one(mode, size, args.count, master, cpp)
            first, rest = lat[0], sorted(lat[1:])
            med = statistics.median(rest)
            p99 = rest[min(len(rest) - 1, int(len(rest) * 0.99))]
            table[(size, mode)] = (med, p99, first)
            label = f"{size >> 20}M" if size >= 1 << 20 else f"{size >> 10}K"
            row = f"{label:>6} {mode:>7} {med * 1e6:>10.0f} {p99 * 1e6:>9.0f} {first * 1e6:>9.0f} {cpu:>8.1%}"
            print(row, flush=True)
    small = min(sizes)
    for big in sorted({s for s in sizes if s == 8 << 20} | {max(sizes)}):  # 8 MB: the bar
        loan_big, loan_small = table.get((big, "loan")), table.get((small, "loan"))
        if loan_big and loan_small and big != small:
            print(f"loan: median at {big} bytes = {loan_big[0] / loan_small[0]:.2f}x that at {small} bytes")
            for mode in modes:
                other = table.get((big, mode))
                if other and mode != "loan":
                    print(f"{mode} / loan median at {big} bytes: {other[0] / loan_big[0]:.1f}x")
    return 0


# --- the coordinator -----------------------------------------------------------------------------------


def _line(proc: subprocess.Popen[bytes], prefix: str, timeout: float = 120.0) -> str:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], deadline - time.monotonic())
        if not ready:
            break
        line = proc.stdout.readline().decode()  # one line per select: our children print one at a time
        if not line:
            break
        if line.startswith(prefix):
            return line[len(prefix) :].strip()
    raise RuntimeError(f"no {prefix!r} line from {proc.args!r}")


def _spawn(*argv: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "bench.shm", *argv],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        start_new_session=True,
    )


def _one(transport: str, size_mb: int, subs: int, master: str, pace_ms: float = 0.0) -> dict[str, float]:
    count = COUNTS[size_mb]
    common = ["--transport", transport, "--size", str(size_mb << 20), "--count", str(count), "--master", master]
    common += ["--pace-ms", str(pace_ms)]
    procs: list[subprocess.Popen[bytes]] = []
    try:
        pub = _spawn("--role", "pub", "--subs", str(subs), *common)
        procs.append(pub)
        if transport == "shm":
            address, token = _line(pub, "addr").split()
            extra = ["--address", address, "--token", token]
        else:
            _line(pub, "ready")
            extra = []
        subs_p = [_spawn("--role", "sub", *common, *extra) for _ in range(subs)]
        procs += subs_p
        _line(pub, "attached")
        results = [json.loads(_line(p, "sub")) for p in subs_p]
        assert pub.stdin is not None
        pub.stdin.write(b"done\n")
        pub.stdin.flush()
        info = json.loads(_line(pub, "pub"))
        secs = max(r["last"] for r in results) - info["t0"]
        return {
            "MBps": count * (size_mb << 20) / 1e6 / secs,
            "cpu_ms": info["cpu"] * 1e3,
            "dropped": float(sum(r["dropped"] for r in results)),
        }
    finally:
        _reap(procs)


def _reap(procs: list[subprocess.Popen[bytes]]) -> None:
    """Wait for each process (they end on their own once told "done"); kill one that does not."""
    for p in procs:
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start_master() -> tuple[subprocess.Popen[bytes], str]:
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "mrosd.master", "--host", "127.0.0.1", "--port", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc, f"http://127.0.0.1:{port}/"
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("the mrosd master did not start")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.shm", description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--sizes", default="1,8", help="message sizes in MB (1 and/or 8)")
    parser.add_argument("--subs", default="1,4", help="subscriber counts")
    parser.add_argument("--transports", default="shm,tcpros")
    parser.add_argument("--pace-ms", type=float, default=0.0, help="pause between two messages (0: back to back)")
    parser.add_argument("--latency", action="store_true", help="one-way latency per size and mode (see above)")
    parser.add_argument(
        "--lat-sizes", default="1024,65536,1048576,8388608,67108864", help="latency message sizes, bytes"
    )
    parser.add_argument("--modes", default="loan,copy,pool,tcpros,roscpp", help="latency modes")
    parser.add_argument("--mode", help=argparse.SUPPRESS)
    parser.add_argument("--role", choices=["pub", "sub", "lpub", "lsub"], help=argparse.SUPPRESS)
    parser.add_argument("--transport", help=argparse.SUPPRESS)
    parser.add_argument("--size", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--count", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--master", default="", help=argparse.SUPPRESS)
    parser.add_argument("--address", help=argparse.SUPPRESS)
    parser.add_argument("--token", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    # the tcpros rows go through mrosd.Node: keep them on TCPROS whatever the caller's environment says (the
    # shared-memory rows drive the endpoints directly)
    os.environ["MROSD_SHM"] = "1" if args.mode == "loan" or args.transport == "loan" else "0"
    if args.role:
        try:
            import uvloop

            uvloop.install()
        except ImportError:
            pass
        roles = {"pub": _pub, "sub": _sub, "lpub": _lat_pub, "lsub": _lat_sub}
        asyncio.run(roles[args.role](args))
        return 0
    master, uri = _start_master()
    if args.latency:
        if args.count is None:
            args.count = 100
        try:
            return _latency(args, uri)
        finally:
            master.terminate()
            master.wait(10)
    sizes = [int(s) for s in args.sizes.split(",")]
    counts = [int(s) for s in args.subs.split(",")]
    transports = args.transports.split(",")
    runs: dict[tuple[int, int, str], list[dict[str, float]]] = {}
    try:
        for _ in range(args.rounds):
            for size in sizes:
                for subs in counts:
                    for transport in transports:
                        runs.setdefault((size, subs, transport), []).append(
                            _one(transport, size, subs, uri, args.pace_ms)
                        )
    finally:
        master.terminate()
        master.wait(10)
    print(f"{'size':>5} {'subs':>4} {'transport':>9} {'MB/s per sub':>12} {'pub CPU/msg':>12} {'drops':>5}")
    table: dict[tuple[int, int, str], dict[str, float]] = {}
    for (size, subs, transport), results in sorted(runs.items()):
        med = {k: statistics.median(r[k] for r in results) for k in results[0]}
        table[(size, subs, transport)] = med
        print(
            f"{size:>4}M {subs:>4} {transport:>9} {med['MBps']:>12.0f} {med['cpu_ms']:>10.2f}ms {med['dropped']:>5.0f}"
        )
    for size in sizes:
        for subs in counts:
            shm, tcp = table.get((size, subs, "shm")), table.get((size, subs, "tcpros"))
            if shm and tcp:
                print(
                    f"{size}M x{subs}: shared memory {shm['MBps'] / tcp['MBps']:.1f}x the TCPROS throughput, "
                    f"publisher CPU/msg {shm['cpu_ms'] / tcp['cpu_ms']:.2f}x"
                )
        one, four = table.get((size, 1, "shm")), table.get((size, 4, "shm"))
        if one and four:
            ratio = four["cpu_ms"] / one["cpu_ms"]
            print(f"{size}M shared memory: publisher CPU/msg with 4 subscribers = {ratio:.2f}x with 1")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
