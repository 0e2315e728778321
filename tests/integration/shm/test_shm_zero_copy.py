"""Zero-copy subscribers through ``mrosd.Node`` (issue 25 (b)): typed messages whose arrays are read-only views
into the publisher's pool, leased until released or dropped, at most ``max_leased`` at once."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import spin
from mrosd.errors import LocalProtocolError
from mrosd.master import Master
from mrosd.msg import get_message_class

Image = get_message_class("sensor_msgs/Image")
String = get_message_class("std_msgs/String")
FRAME = 640 * 480 * 3


def node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


def image(i: int) -> Any:
    return Image(height=480, width=640, encoding="rgb8", step=1920, data=bytes([i]) * FRAME)


async def test_a_zero_copy_subscriber_gets_typed_views_leased_until_released_or_dropped() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("talker", master.uri) as a:
        pub = await a.advertise("/image", Image, queue_size=2, max_message_size=FRAME + 4096)
        async with node("viewer", master.uri) as b:
            sub = await b.subscribe("/image", Image, zero_copy=True, max_leased=2)
            await pub.wait_for_subscribers(1, timeout=10)
            await sub.wait_for_publishers(1, timeout=10)
            assert [row[3] for row in b.subscribers["/image"].bus_info()] == ["SHMROS"]
            await pub.publish(image(1))
            first = await sub.next(timeout=5)
            assert isinstance(first, Image) and first.encoding == "rgb8" and first.width == 640
            assert isinstance(first.data, memoryview) and first.data.readonly and len(first.data) == FRAME
            assert first.data.obj.__class__.__name__ == "mmap"  # the publisher's pool itself: no copy
            with first.data[:16] as head:
                assert bytes(head) == b"\x01" * 16
            endpoint = pub.shm.endpoint  # type: ignore[union-attr]
            link = endpoint.links[0]
            assert link.grant == 2 and link.leases()

            for i in range(2, 12):  # laps the pool: never the leased slot
                await pub.publish(image(i))
                await asyncio.sleep(0.01)
            second = await sub.next(timeout=5)  # the second lease
            assert bytes(first.data[-8:]) == b"\x01" * 8  # still frame 1, however many frames went by
            await asyncio.sleep(0.05)
            assert len(link.leases()) == 2
            dropped_before = sub.stats()[1][0][3]
            assert dropped_before > 0  # both leases held: later frames were dropped (counted), not waited for

            with first:
                pass  # released: its slot may be reused
            assert len(link.leases()) == 1
            del second  # dropped: its lease ends with it
            await pub.publish(image(20))
            third = await sub.next(timeout=5)
            assert bytes(third.data[:4]) == b"\x14" * 4
            third.release()
            assert not link.leases()
            assert endpoint.rings_made == 1  # the pool made at advertise time served every frame


async def test_a_zero_copy_subscriber_of_a_publisher_without_a_pool_gets_copies_with_the_same_api() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("talker", master.uri) as a:
        pub = await a.advertise("/chatter", String)
        async with node("listener", master.uri) as b:
            sub = await b.subscribe("/chatter", String, zero_copy=True)
            await pub.wait_for_subscribers(1, timeout=10)
            await sub.wait_for_publishers(1, timeout=10)
            await pub.publish(String(data="hi"))
            msg = await sub.next(timeout=5)
            with msg:
                assert msg.data == "hi" and isinstance(msg, String)


async def test_a_loan_is_filled_in_place_published_without_a_copy_and_only_once() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("camera", master.uri) as a:
        pub = await a.advertise("/image", Image, queue_size=2, max_message_size=FRAME + 4096)
        async with node("viewer", master.uri) as b, node("tcp_viewer", master.uri) as c:
            sub = await b.subscribe("/image", Image, zero_copy=True)
            await sub.wait_for_publishers(1, timeout=10)
            assert [row[3] for row in sub.bus_info()] == ["SHMROS"]
            os.environ["MROSD_SHM"] = "0"  # c's next connection: TCPROS (read when it asks for the topic)
            try:
                tcp = await c.subscribe("/image", Image)
                await tcp.wait_for_publishers(1, timeout=10)
            finally:
                os.environ["MROSD_SHM"] = "1"
            await pub.wait_for_subscribers(2, timeout=10)
            await sub.wait_for_publishers(1, timeout=10)
            assert [row[3] for row in tcp.bus_info()] == ["TCPROS"]
            endpoint = pub.shm.endpoint  # type: ignore[union-attr]
            for i in range(1, 4):
                msg = pub.loan(data=FRAME)
                assert isinstance(msg, Image) and len(msg.data) == FRAME and not msg.data.readonly
                assert msg.data.obj is endpoint.ring.map  # the pool itself
                msg.data[:] = bytes([i]) * FRAME  # as np.frombuffer(msg.data, np.uint8)[:] = i would
                msg.height, msg.width, msg.encoding, msg.step = 480, 640, "rgb8", 1920
                msg.header.frame_id = "camera"
                await pub.publish(msg)
                with pytest.raises(LocalProtocolError, match="published already"):
                    await pub.publish(msg)
                with pytest.raises(ValueError):
                    msg.data[0] = 1  # the view went with the publish
                got = await sub.next(timeout=5)
                assert got._shm_lease is not None  # a view of the slot
                with got:
                    assert got.header.frame_id == "camera" and got.encoding == "rgb8" and got.header.seq == i - 1
                    assert bytes(got.data[:3]) == bytes([i]) * 3 and bytes(got.data[-3:]) == bytes([i]) * 3
                over_tcp = await tcp.next(timeout=5)
                assert over_tcp.header.frame_id == "camera" and bytes(over_tcp.data[-3:]) == bytes([i]) * 3
                assert len(over_tcp.data) == FRAME
            template = pub.loan(image(7))
            assert template.encoding == "rgb8" and len(template.data) == FRAME and bytes(template.data[:1]) != b"\x07"
            del template  # never published: its slot comes back
            assert not endpoint._loaned
            assert endpoint.rings_made == 1


async def test_a_frame_handed_to_a_worker_thread_is_released_there() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("camera", master.uri) as a:
        pub = await a.advertise("/image", Image, queue_size=2, max_message_size=FRAME + 4096)
        async with node("viewer", master.uri) as b:
            sub = await b.subscribe("/image", Image, zero_copy=True, max_leased=1)
            await pub.wait_for_subscribers(1, timeout=10)
            await sub.wait_for_publishers(1, timeout=10)
            link = pub.shm.endpoint.links[0]  # type: ignore[union-attr]
            for i in range(3):  # one lease: each frame must come back from the worker for the next to arrive
                await pub.publish(image(i))
                msg = await sub.next(timeout=5)

                def work(frame: Any = msg) -> int:
                    with frame:
                        return int(frame.data[0]) + int(frame.data[-1])

                assert await asyncio.to_thread(work) == 2 * i
                del msg
                assert not link.leases()
            assert sub.stats()[1][0][3] == 0  # nothing dropped: every lease came back in time


@pytest.mark.quiet_cpu
async def test_a_zero_copy_subscriber_spins_through_the_window_of_a_periodic_publishers_next_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pressure = tmp_path / "cpu"  # an idle machine, whatever the one running the test is doing
    pressure.write_text("some avg10=0.00 avg60=0.00 avg300=0.00 total=0\n")
    monkeypatch.setattr(spin, "_PRESSURE_FILE", str(pressure))
    async with Master(host="127.0.0.1", port=0) as master, node("camera", master.uri) as a:
        pub = await a.advertise("/image", Image, queue_size=2, max_message_size=FRAME + 4096)
        async with node("viewer", master.uri) as b:
            sub = await b.subscribe("/image", Image, zero_copy=True)
            await sub.wait_for_publishers(1, timeout=10)
            await pub.wait_for_subscribers(1, timeout=10)
            spinner = spin.loop_spinner()
            assert spinner.anticipated == 0
            for i in range(spin.STEADY + 8):  # 20 Hz: a window of at most 5 ms around each next frame
                msg = pub.loan(data=FRAME)
                msg.data[:4] = bytes([i]) * 4
                await pub.publish(msg)
                got = await sub.next(timeout=5)
                with got:
                    assert bytes(got.data[:4]) == bytes([i]) * 4
                await asyncio.sleep(0.05)
            assert spinner.anticipated >= 3  # windows opened once the rhythm was steady
