"""``python -m bench fleet``: two robots over Zenoh against plain multi-host TCPROS, on the same link, same run.

As root, two network namespaces joined by a veth bridge (tests/netns's lab) are the two hosts:

- **TCPROS (one master)**: the master and an mrosd publisher on host 1, an mrosd subscriber on host 2 that
  connects across the link (what ROS 1 does when two machines share one master);
- **Zenoh (two robots)**: an mrosd daemon with ``[fleet]`` on each host, the publisher on host 1's master, the
  subscriber on host 2's master reading ``/robot1/bench``.

Measured for each: 1 KB one-way latency (the namespaces share the kernel's monotonic clock, so the stamp in
the body is compared with the arrival time), 1 MB and 8 MB messages per second received while the publisher
sends flat out, and for Zenoh the CPU seconds both daemons spent per forwarded MB. Without root, the same two
paths run on loopback in one process each (a smaller, noisier comparison, said so in the output).

Usage: ``python -m bench fleet [--seconds 4]``; ``--role pub|sub`` is the per-host process.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SIZES = [1024, 1_000_000, 8_000_000]
MASTER_PORT = 11311  # tests.fleet.fleetenv's, where the daemons' configuration is written


# --- the per-host processes -----------------------------------------------------------------------


async def _pub(master: str, topic: str, size: int, seconds: float, rate: float) -> None:
    import mrosd
    from mrosd.msg import get_message_class

    array = get_message_class("std_msgs/UInt8MultiArray")
    tail = bytes(max(0, size - 8))
    async with mrosd.Node("bench_pub", master_uri=master, argv=[], rosout=False, logger_services=False) as node:
        pub = await node.advertise(topic, array, queue_size=2)
        await pub.wait_for_subscribers(1, 60)
        stop = time.monotonic() + seconds
        while time.monotonic() < stop:
            pub.publish_nowait(array(data=struct.pack("<q", time.monotonic_ns()) + tail))
            await asyncio.sleep(1.0 / rate if rate > 0 else 0)


async def _sub(master: str, topic: str, seconds: float) -> None:
    import mrosd
    from mrosd.tcpros.subscriber import AnyMsg

    async with mrosd.Node("bench_sub", master_uri=master, argv=[], rosout=False, logger_services=False) as node:
        sub = await node.subscribe(topic, AnyMsg, queue_size=2)
        first = await sub.next(timeout=120)
        count, nbytes, lat = 0, 0, []
        t0 = time.monotonic()
        stop = t0 + seconds
        del first
        while time.monotonic() < stop:
            try:
                msg = await sub.next(timeout=max(0.01, stop - time.monotonic()))
            except TimeoutError:
                break
            now = time.monotonic_ns()
            # UInt8MultiArray: layout (dim count 0, data_offset) = 8 bytes, then the uint8[] length, then data
            (stamp,) = struct.unpack_from("<q", msg.data, 12)
            lat.append((now - stamp) / 1e6)
            count += 1
            nbytes += len(msg.data)
        elapsed = time.monotonic() - t0
        print(
            json.dumps(
                {
                    "msgs_per_s": count / elapsed,
                    "MB_per_s": nbytes / elapsed / 1e6,
                    "lat_median_ms": statistics.median(lat) if lat else float("nan"),
                    "lat_p99_ms": sorted(lat)[int(0.99 * len(lat))] if lat else float("nan"),
                    "count": count,
                }
            ),
            flush=True,
        )


# --- the lab --------------------------------------------------------------------------------------


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class _Lab:
    def __init__(self) -> None:
        sys.path.insert(0, str(ROOT))
        from tests.netns.nsutil import NetnsLab, netns_unavailable

        why = netns_unavailable()
        if why is not None:
            raise RuntimeError(why)
        self.lab = NetnsLab()
        self.lab.setup()
        self.procs: list[subprocess.Popen[bytes]] = []
        self.env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_"))}
        self.env["PYTHONPATH"] = os.pathsep.join([str(ROOT), str(ROOT / "cli")])

    def start(self, host: int, argv: list[str], **env: str) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            self.lab.argv(host, [sys.executable, *argv]),
            env={**self.env, **env},
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        self.procs.append(proc)
        return proc

    def stop_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(5)
            if proc.stdout is not None:
                proc.stdout.close()
        self.procs.clear()

    def close(self) -> None:
        self.stop_all()
        self.lab.teardown()

    def wait_master(self, host: int, uri: str) -> None:
        code = f"import sys; sys.path.insert(0, {str(ROOT)!r}); from tests.rosenv import wait_for_xmlrpc; "
        code += f"wait_for_xmlrpc({uri!r}, 60)"
        self.lab.exec_ok(self.lab.hosts[host], [sys.executable, "-c", code], timeout=70)

    def pair(self, master1: str, master2: str, topic_in: str, topic_out: str, size: int, seconds: float) -> Any:
        rate = "200" if size <= 1024 else "0"
        host_env = {"ROS_HOSTNAME": self.lab.addrs[1]} if master1 == master2 else {"ROS_HOSTNAME": "127.0.0.1"}
        sub = self.start(1, ["-m", "bench.fleet", "--role", "sub", master2, topic_out, "0", str(seconds)], **host_env)
        pub_env = {"ROS_HOSTNAME": self.lab.addrs[0]} if master1 == master2 else {"ROS_HOSTNAME": "127.0.0.1"}
        pub = self.start(
            0, ["-m", "bench.fleet", "--role", "pub", master1, topic_in, str(size), str(seconds + 60), rate], **pub_env
        )
        assert sub.stdout is not None
        line = sub.stdout.readline()
        pub.terminate()
        return json.loads(line) if line else None


def _netns_run(seconds: float) -> dict[str, dict[int, Any]]:
    from tests.fleet.fleetenv import daemon_config

    lab = _Lab()
    results: dict[str, dict[int, Any]] = {"tcpros": {}, "zenoh": {}}
    try:
        addr1 = lab.lab.addrs[0]
        shared = f"http://{addr1}:{MASTER_PORT}/"
        lab.start(0, ["-m", "mrosd.master", "--host", "0.0.0.0", "--port", str(MASTER_PORT)])
        lab.wait_master(0, shared)
        for size in SIZES:
            results["tcpros"][size] = lab.pair(shared, shared, "/bench", "/bench", size, seconds)
        lab.stop_all()
        tmp = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
        local = f"http://127.0.0.1:{MASTER_PORT}/"
        daemons = []
        for i, (robot, connect, extra) in enumerate(
            [("robot1", "", 'send_topics = ["/bench"]\n'), ("robot2", addr1, 'receive_topics = ["/robot1/**"]\n')]
        ):
            cfg = daemon_config(tmp, robot, lab.lab.addrs[i], connect, extra + "queue_size = 4\n")
            daemons.append(lab.start(i, ["-m", "mrosd.daemon", "--config", str(cfg)], ROS_HOSTNAME="127.0.0.1"))
        for i in range(2):
            lab.wait_master(i, local)
        for size in SIZES:
            cpu0 = sum(_cpu_seconds(d.pid) for d in daemons)
            res = lab.pair(local, local, "/bench", "/robot1/bench", size, seconds)
            cpu1 = sum(_cpu_seconds(d.pid) for d in daemons)
            if res:
                # the window the subscriber counted plus the start-up around it: an upper bound per MB
                res["daemon_cpu_s_per_MB"] = (cpu1 - cpu0) / max(1e-9, res["MB_per_s"] * seconds)
            results["zenoh"][size] = res
    finally:
        lab.close()
    return results


# --- loopback fallback ----------------------------------------------------------------------------


async def _loopback(seconds: float) -> dict[str, dict[int, Any]]:
    import mrosd
    from mrosd.master import Master
    from mrosd.msg import get_message_class
    from tests.fleet.fleetenv import fleet

    array = get_message_class("std_msgs/UInt8MultiArray")

    async def measure(pub: Any, sub: Any, size: int) -> dict[str, float]:
        tail = bytes(size - 8)
        count, lat = 0, []
        stop = time.monotonic() + seconds

        async def send() -> None:
            while time.monotonic() < stop:
                pub.publish_nowait(array(data=struct.pack("<q", time.monotonic_ns()) + tail))
                await asyncio.sleep(0.005 if size <= 1024 else 0)

        task = asyncio.create_task(send())
        t0 = time.monotonic()
        while time.monotonic() < stop:
            try:
                msg = await sub.next(timeout=1)
            except TimeoutError:
                break
            lat.append((time.monotonic_ns() - struct.unpack_from("<q", bytes(msg.data[:8]))[0]) / 1e6)
            count += 1
        task.cancel()
        elapsed = time.monotonic() - t0
        return {
            "msgs_per_s": count / elapsed,
            "MB_per_s": count * size / elapsed / 1e6,
            "lat_median_ms": statistics.median(lat),
            "lat_p99_ms": sorted(lat)[int(0.99 * len(lat))],
        }

    def node(name: str, uri: str) -> mrosd.Node:
        return mrosd.Node(name, master_uri=uri, argv=[], host="127.0.0.1", rosout=False, logger_services=False)

    out: dict[str, dict[int, Any]] = {"tcpros": {}, "zenoh": {}}
    for size in SIZES:
        async with Master(host="127.0.0.1", port=0) as m, node("a", m.uri) as a, node("b", m.uri) as b:
            pub = await a.advertise("/bench", array, queue_size=2)
            sub = await b.subscribe("/bench", array, queue_size=2)
            await pub.wait_for_subscribers(1, 10)
            out["tcpros"][size] = await measure(pub, sub, size)
        async with fleet("robot1", "robot2") as (r1, r2), r1.node("a") as a, r2.node("b") as b:
            pub = await a.advertise("/bench", array, queue_size=2)
            pub.publish_nowait(array(data=bytes(8)))
            await r2.bridge.wait_until(lambda: "/robot1/bench" in r2.bridge.received, 15)
            sub = await b.subscribe("/robot1/bench", array, queue_size=2)
            await r1.bridge.wait_until(lambda: r1.bridge.sent["/bench"].matched, 15)
            out["zenoh"][size] = await measure(pub, sub, size)
    return out


def _report(results: dict[str, dict[int, Any]], where: str) -> None:
    print(f"fleet benchmark ({where})")
    for path in ("tcpros", "zenoh"):
        for size, r in results[path].items():
            if r is None:
                print(f"  {path:7} {size:>9} B: no data")
                continue
            extra = f"  daemons {r['daemon_cpu_s_per_MB'] * 1e3:.1f} ms CPU/MB" if "daemon_cpu_s_per_MB" in r else ""
            print(
                f"  {path:7} {size:>9} B: {r['msgs_per_s']:8.1f} msg/s {r['MB_per_s']:8.1f} MB/s  "
                f"latency median {r['lat_median_ms']:.2f} ms p99 {r['lat_p99_ms']:.2f} ms{extra}"
            )
    for size in SIZES[1:]:
        t, z = results["tcpros"].get(size), results["zenoh"].get(size)
        if t and z and t["msgs_per_s"] > 0:
            print(f"  {size} B throughput zenoh / tcpros = {z['msgs_per_s'] / t['msgs_per_s']:.2f} (bar: >= 0.5)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench fleet")
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--role", choices=["pub", "sub"])
    parser.add_argument("args", nargs="*")
    opts = parser.parse_args(argv if argv is not None else sys.argv[1:])
    from mrosd.loop import run

    if opts.role == "pub":
        master, topic, size, seconds, rate = opts.args
        run(_pub(master, topic, int(size), float(seconds), float(rate)))
        return 0
    if opts.role == "sub":
        master, topic, _size, seconds = opts.args
        run(_sub(master, topic, float(seconds)))
        return 0
    from mrosd.fleet.bridge import require_zenoh

    require_zenoh()  # says what to install when eclipse-zenoh is missing
    if os.geteuid() == 0:
        _report(_netns_run(opts.seconds), "two network namespaces over a veth bridge")
    else:
        _report(run(_loopback(opts.seconds)), "loopback, one process per path: not root, no netns")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
