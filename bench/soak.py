"""Load and soak: many nodes, many topics, a hot topic with a wide fan-out and a stalled subscriber, for minutes.

``python -m bench.soak --minutes 10`` runs the full scenario: the mrosd daemon (master + IXM + rosout) in its own
process; 200 real ``mrosd.Node`` s spread over worker processes (each node has its own slave XML-RPC server and
TCPROS listener, exactly as separate programs would); 2000 topics (10 per node) each published every 2 s; every
node subscribes to one random other topic; 100 nodes subscribe to ``/hot``, published at 100 Hz; parameters are
set and read every second; each worker opens a new IXM shared-memory key every second and closes the one
opened 10 s before; every 5 s each worker closes one node and starts a new one (registration churn). A
raw TCP subscriber of ``/hot`` completes the handshake and then never reads: the publisher must drop for it, not
buffer. Every ``--interval`` seconds the RSS and open fds of the daemon and of every worker, and the IXM
segments held open (nameless memfds, found through /proc/*/fd), are sampled and printed.

Pass (exit 0) when, between the sample after warm-up (a quarter of the run) and the last one: no RSS grew by
more than 25 % + 20 MiB, no fd count grew by more than 32 (plus a few per IXM key opened since), the daemon's
live segments stay within the keys the workers hold open and none is held by any process once everything
stopped, ``/hot`` kept being delivered, and no worker reported an error. ``--seconds`` and the size options make
the short version the test suite runs (tests/reliability/test_reliability_soak.py).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

HOT = "/hot"


# --- worker: many nodes in one process ------------------------------------------------------------------------


async def worker(args: argparse.Namespace) -> None:
    import mrosd
    from mrosd.msg import get_message_class

    string = get_message_class("std_msgs/String")
    w, workers, nodes = args.worker, args.workers, args.nodes
    per_node = max(1, args.topics // nodes)
    mine = [i for i in range(nodes) if i % workers == w]
    counters = {"hot_rx": 0, "rx": 0, "tx": 0, "errors": 0, "churn": 0}
    live: dict[int, Any] = {}
    rng = random.Random(w)

    def on_hot(_msg: Any) -> None:
        counters["hot_rx"] += 1

    def on_any(_msg: Any) -> None:
        counters["rx"] += 1

    async def start_node(i: int, generation: int) -> None:
        node = mrosd.Node(f"soak_n{i}_g{generation}", argv=[], host="127.0.0.1", watchdog_interval=5.0)
        await node.start()
        pubs = [await node.advertise(f"/t/n{i}/t{j}", string) for j in range(per_node)]
        if i == 0:
            pubs.append(await node.advertise(HOT, string, queue_size=10))
        if 1 <= i <= args.fanout:
            await node.subscribe(HOT, string, callback=on_hot)
        other = rng.randrange(nodes)
        await node.subscribe(f"/t/n{other}/t{rng.randrange(per_node)}", string, callback=on_any)
        live[i] = (node, pubs)

    for i in mine:
        await start_node(i, 0)
    print(json.dumps({"worker": w, "ready": True}), flush=True)

    async def slow_traffic() -> None:
        while True:
            for _node, pubs in list(live.values()):
                for pub in pubs[:per_node]:
                    await pub.publish(string(data="x" * 64))
                    counters["tx"] += 1
            await asyncio.sleep(2.0)

    async def hot_traffic() -> None:
        payload = string(data="h" * 256)
        while True:
            entry = live.get(0)
            if entry is not None:
                await entry[1][-1].publish(payload)
                counters["tx"] += 1
            await asyncio.sleep(1 / args.hot_rate)

    from mrosd.ixm.client import IxmClient

    ixm = IxmClient(name=f"soak-worker{w}", timeout=5)
    keys: dict[int, Any] = {}

    def ixm_churn(tick: int) -> None:
        """Open a new shared-memory key each second, write it, close the one opened 10 s earlier."""
        key = ixm.open(f"/soak/w{w}/k{tick}", "float64", count=1024, mode="rw")
        key.write([float(tick)] * 1024)
        keys[tick] = key
        old = keys.pop(tick - 10, None)
        if old is not None:
            assert old.read()[0] == float(tick - 10)
            old.close()

    async def params_and_churn() -> None:
        tick = 0
        while True:
            await asyncio.sleep(1.0)
            tick += 1
            try:
                node = next(iter(live.values()))[0]
                await node.set_param(f"/soak/w{w}", {"tick": tick, "blob": "p" * 512})
                assert (await node.get_param(f"/soak/w{w}"))["tick"] == tick
                ixm_churn(tick)
                if tick % 5 == 0:
                    victims = [i for i in live if i > args.fanout]  # keep the hot topic's graph stable
                    if victims:
                        i = rng.choice(victims)
                        old, _ = live.pop(i)
                        await old.aclose()
                        await start_node(i, tick)
                        counters["churn"] += 1
            except Exception as exc:
                counters["errors"] += 1
                print(json.dumps({"worker": w, "error": repr(exc)}), flush=True)
            print(json.dumps({"worker": w, **counters}), flush=True)

    tasks = [asyncio.create_task(slow_traffic()), asyncio.create_task(params_and_churn())]
    if 0 in mine:
        tasks.append(asyncio.create_task(hot_traffic()))
    stop = asyncio.Event()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    await stop.wait()
    for t in tasks:
        t.cancel()
    for node, _ in live.values():
        await node.aclose()
    ixm.close()


# --- controller -----------------------------------------------------------------------------------------------


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


#: fds one open IXM key may hold in one process (see the fd check in run()).
FDS_PER_LIVE_KEY = 4


def fd_count(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def shm_entries(prefix: str) -> set[str]:
    """Names of the IXM segments (nameless memfds) with ``prefix`` that any process holds open."""
    from mrosd.ixm.resources import held_memfds

    return held_memfds(prefix)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_master(uri: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            with xmlrpc.client.ServerProxy(uri) as p:
                p.getPid("/soak")
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def stall_subscriber(master_uri: str) -> socket.socket | None:
    """Connect to /hot's publisher, complete the handshake, then never read (a stalled subscriber)."""
    with xmlrpc.client.ServerProxy(master_uri) as m:
        code, _, api = m.lookupNode("/soak", "/soak_n0_g0")
    if code != 1:
        return None
    with xmlrpc.client.ServerProxy(api) as slave:
        _, _, proto = slave.requestTopic("/soak_slow", HOT, [["TCPROS"]])
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((proto[1], proto[2]))
    fields = [b"callerid=/soak_slow", b"topic=" + HOT.encode(), b"md5sum=*", b"type=std_msgs/String", b"tcp_nodelay=0"]
    body = b"".join(struct.pack("<I", len(f)) + f for f in fields)
    sock.sendall(struct.pack("<I", len(body)) + body)
    return sock


def run(args: argparse.Namespace) -> int:
    seconds = args.seconds if args.seconds is not None else args.minutes * 60
    tmp = Path(tempfile.mkdtemp(prefix="mrosd-soak-"))
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(
        ROS_MASTER_URI=uri,
        ROS_HOSTNAME="127.0.0.1",
        MROSD_MASTER_HOST="127.0.0.1",
        MROSD_IXM_SOCKET=str(tmp / "ixm.sock"),
        ROS_HOME=str(tmp),
    )
    from mrosd.ixm.server import segment_prefix

    prefix = segment_prefix(str(tmp / "ixm.sock"))
    shm_before = shm_entries(prefix)
    procs: list[subprocess.Popen[bytes]] = []
    ok = True
    try:
        daemon = subprocess.Popen(
            [sys.executable, "-m", "mrosd.daemon", "--port", str(port), "--log-level", "error"],
            env=env,
            stdout=subprocess.DEVNULL,
            start_new_session=True,
        )
        procs.append(daemon)
        wait_master(uri)
        base = [
            sys.executable,
            "-m",
            "bench.soak",
            "--worker-of",
            str(args.workers),
            "--nodes",
            str(args.nodes),
            "--topics",
            str(args.topics),
            "--fanout",
            str(args.fanout),
            "--hot-rate",
            str(args.hot_rate),
            *(["--uvloop"] if args.uvloop else []),
        ]
        workers = [
            subprocess.Popen(
                [*base, "--worker", str(w)],
                env=env,
                stdout=subprocess.PIPE,
                start_new_session=True,
                cwd=Path(__file__).resolve().parent.parent,
            )
            for w in range(args.workers)
        ]
        procs += workers
        last: dict[int, dict[str, Any]] = {}
        for p in workers:
            assert p.stdout is not None
            os.set_blocking(p.stdout.fileno(), False)
        started = time.monotonic()
        ready: set[int] = set()
        buffers = {w: b"" for w in range(len(workers))}

        def drain() -> None:
            for w, p in enumerate(workers):
                assert p.stdout is not None
                try:
                    chunk = p.stdout.read()
                except BlockingIOError:
                    chunk = None
                if chunk:
                    buffers[w] += chunk
                *lines, buffers[w] = buffers[w].split(b"\n")
                for line in lines:
                    msg = json.loads(line)
                    if msg.get("ready"):
                        ready.add(w)
                    elif "error" in msg:
                        print(f"  worker {w} error: {msg['error']}", flush=True)
                    else:
                        last[w] = msg

        while len(ready) < len(workers):
            drain()
            if any(p.poll() is not None for p in workers) or time.monotonic() - started > 120:
                print("FAIL: workers did not start", flush=True)
                return 1
            time.sleep(0.1)
        print(
            f"{args.nodes} nodes, {args.topics} topics, {args.fanout} subscribers of {HOT} at {args.hot_rate:g} Hz, "
            f"{args.workers} worker processes; started in {time.monotonic() - started:.1f} s",
            flush=True,
        )
        slow = stall_subscriber(uri)
        print(f"stalled raw subscriber of {HOT}: {'connected' if slow else 'FAILED to connect'}", flush=True)
        ok = slow is not None

        samples: list[dict[str, Any]] = []
        t0 = time.monotonic()
        print(
            f"{'t(s)':>6} {'daemon RSS MiB':>15} {'fds':>5} {'workers RSS MiB':>24} {'fds':>16} {'/hot rx':>9} "
            f"{'tx':>9} {'churn':>5} {'errors':>6} {'shm':>4}",
            flush=True,
        )
        hot_seen: dict[int, int] = {}
        while True:
            time.sleep(min(args.interval, max(0.0, seconds - (time.monotonic() - t0))) or 0.01)
            drain()
            for p in procs:
                if p.poll() is not None:
                    print(f"FAIL: process {p.args[:4]} exited with {p.returncode}", flush=True)
                    return 1
            s = {
                "t": time.monotonic() - t0,
                "rss": [rss_kib(p.pid) for p in procs],
                "fds": [fd_count(p.pid) for p in procs],
                "hot": sum(v.get("hot_rx", 0) for v in last.values()),
                "tx": sum(v.get("tx", 0) for v in last.values()),
                "churn": sum(v.get("churn", 0) for v in last.values()),
                "errors": sum(v.get("errors", 0) for v in last.values()),
                "shm": len(shm_entries(prefix) - shm_before),
            }
            samples.append(s)
            wr = "/".join(f"{r / 1024:.0f}" for r in s["rss"][1:])
            wf = "/".join(str(f) for f in s["fds"][1:])
            print(
                f"{s['t']:6.0f} {s['rss'][0] / 1024:15.1f} {s['fds'][0]:5d} {wr:>24} {wf:>16} {s['hot']:9d} "
                f"{s['tx']:9d} {s['churn']:5d} {s['errors']:6d} {s['shm']:4d}",
                flush=True,
            )
            for w, v in last.items():
                hot_seen.setdefault(w, v.get("hot_rx", 0))
            if s["t"] >= seconds:
                break

        warm = samples[max(0, len(samples) // 4 - 1)] if len(samples) > 1 else samples[0]
        end = samples[-1]
        names = ["daemon"] + [f"worker{w}" for w in range(len(workers))]
        # A live IXM key holds a few fds in the daemon and its client (segment memfd, writers' lock memfd,
        # notice page, the reader's wake-up pipe); keys still being opened after warm-up are allowed for, leaks are not.
        fd_slack = 32 + FDS_PER_LIVE_KEY * max(0, end["shm"] - warm["shm"])
        for name, r0, r1, f0, f1 in zip(names, warm["rss"], end["rss"], warm["fds"], end["fds"], strict=True):
            bound = r0 * 1.25 + 20 * 1024
            verdict = "ok" if r1 <= bound and f1 <= f0 + fd_slack else "GREW"
            ok &= verdict == "ok"
            print(
                f"  {name:8} RSS {r0 / 1024:7.1f} -> {r1 / 1024:7.1f} MiB (bound {bound / 1024:.1f}), "
                f"fds {f0} -> {f1}: {verdict}",
                flush=True,
            )
        hot_total = end["hot"] - warm["hot"]
        live_keys = 10 * len(workers)  # each worker keeps its last 10 IXM keys open
        print(
            f"  /hot deliveries after warm-up: {hot_total}; errors: {end['errors']}; "
            f"IXM segments alive: {end['shm']} (bound {live_keys + len(workers)})"
        )
        ok &= hot_total > 0 and end["errors"] == 0 and end["shm"] <= live_keys + len(workers)
        if slow is not None:
            slow.close()
    finally:
        for p in reversed(procs):  # workers first and waited for, then the daemon
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5)
            if p.stdout is not None:
                p.stdout.close()
    leaked = shm_entries(prefix) - shm_before
    if leaked:
        print(f"FAIL: IXM segments still held after the run: {sorted(leaked)}")
        ok = False
    print("PASS" if ok else "FAIL", flush=True)
    return 0 if ok else 1


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.soak", description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, help="run length in seconds (overrides --minutes)")
    parser.add_argument("--nodes", type=int, default=200)
    parser.add_argument("--topics", type=int, default=2000)
    parser.add_argument("--fanout", type=int, default=100, help=f"subscribers of {HOT}")
    parser.add_argument("--hot-rate", type=float, default=100.0)
    parser.add_argument("--workers", type=int, default=4)
    parser.add_argument("--interval", type=float, default=10.0, help="seconds between samples")
    parser.add_argument("--uvloop", action="store_true", help="run the worker nodes on uvloop")
    parser.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--worker-of", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker is not None:
        args.workers = args.worker_of
        if args.uvloop:
            import uvloop

            uvloop.install()
        asyncio.run(worker(args))
        return 0
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
