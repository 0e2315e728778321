"""``python -m bench fleet``: two robots linked over Zenoh against plain TCPROS with one master, same run.

Both paths run on loopback in one process (two mrosd masters + FleetBridge each; and one master with the
same publisher and subscriber nodes), so the ratio compares the transports, not the machines. 1 KB: one-way
latency (same clock); 1 MB: messages per second a subscriber receives while the publisher sends flat out.
"""

from __future__ import annotations

import asyncio
import statistics
import time
from typing import Any

import mrosd
from mrosd.loop import run
from mrosd.master import Master
from mrosd.msg import get_message_class

UInt8Array = get_message_class("std_msgs/UInt8MultiArray")
LAT_COUNT = 300
THR_SECONDS = 4.0


def _node(name: str, uri: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=uri, argv=[], host="127.0.0.1", rosout=False, logger_services=False)


async def _measure(pub: Any, sub: Any, size: int, count: int | None, seconds: float | None) -> dict[str, float]:
    payload = bytes(size - 8)
    lat: list[float] = []
    got = 0
    if count is not None:  # latency: one at a time
        for _ in range(count):
            t0 = time.perf_counter()
            await pub.publish(UInt8Array(data=payload))
            await sub.next(timeout=10)
            lat.append(time.perf_counter() - t0)
        return {"median_ms": statistics.median(lat) * 1e3, "p99_ms": sorted(lat)[int(0.99 * len(lat))] * 1e3}
    assert seconds is not None
    stop = time.perf_counter() + seconds

    async def send() -> None:
        while time.perf_counter() < stop:
            await pub.publish(UInt8Array(data=payload))
            await asyncio.sleep(0)

    task = asyncio.create_task(send())
    t0 = time.perf_counter()
    while time.perf_counter() < stop:
        try:
            await sub.next(timeout=1)
            got += 1
        except TimeoutError:
            break
    task.cancel()
    elapsed = time.perf_counter() - t0
    return {"msgs_per_s": got / elapsed, "MB_per_s": got * size / elapsed / 1e6}


async def _tcpros(size: int, count: int | None, seconds: float | None) -> dict[str, float]:
    async with Master(host="127.0.0.1", port=0) as m, _node("a", m.uri) as a, _node("b", m.uri) as b:
        pub = await a.advertise("/bench", UInt8Array, queue_size=4)
        sub = await b.subscribe("/bench", UInt8Array, queue_size=4)
        await pub.wait_for_subscribers(1, 10)
        return await _measure(pub, sub, size, count, seconds)


async def _zenoh(size: int, count: int | None, seconds: float | None) -> dict[str, float]:
    from tests.fleet.fleetenv import fleet

    async with fleet("robot1", "robot2") as (r1, r2), r1.node("a") as a, r2.node("b") as b:
        pub = await a.advertise("/bench", UInt8Array, queue_size=4)
        await pub.publish(UInt8Array(data=b"warm"))
        await pub.wait_for_subscribers(1, 10)  # the fleet node
        while "/robot1/bench" not in r2.bridge.received:
            await pub.publish(UInt8Array(data=b"warm"))
            await asyncio.sleep(0.1)
        sub = await b.subscribe("/robot1/bench", UInt8Array, queue_size=4)
        await sub.wait_for_publishers(1, 10)
        while True:  # until the link carries data
            await pub.publish(UInt8Array(data=b"warm"))
            try:
                await sub.next(timeout=0.2)
                break
            except TimeoutError:
                continue
        return await _measure(pub, sub, size, count, seconds)


async def bench() -> None:
    for name, fn in (("tcpros (one master)", _tcpros), ("zenoh (two robots)", _zenoh)):
        lat = await fn(1024, LAT_COUNT, None)
        thr = await fn(1_000_000, None, THR_SECONDS)
        print(
            f"{name:22} 1 KB latency median {lat['median_ms']:.3f} ms p99 {lat['p99_ms']:.3f} ms; "
            f"1 MB {thr['msgs_per_s']:.1f} msg/s ({thr['MB_per_s']:.0f} MB/s)"
        )
        results[name] = thr["msgs_per_s"]
    ratio = results["zenoh (two robots)"] / results["tcpros (one master)"]
    print(f"1 MB throughput zenoh / tcpros = {ratio:.2f} (bar: >= 0.5)")


results: dict[str, float] = {}


def main(argv: list[str] | None = None) -> int:
    run(bench())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
