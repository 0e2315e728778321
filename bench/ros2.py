"""``python -m bench ros2``: the ros2 bridge (``mros ros2 bridge``) against a plain TCPROS hop, in the same run.

One Debian rosmaster, one Zenoh router (in this process, as ``rmw_zenohd`` would be) and the bridge in its own
process, whose CPU time is read from /proc. For each size (1 KB at 1 kHz, 1 MB at 100 Hz, 1080p rgb8 = 6.2 MB
at 30 Hz), ``sensor_msgs/Image`` stamped with the send time, for ``--seconds`` each:

- **TCPROS**: an mrosd publisher -> an mrosd subscriber (the hop every ROS 1 topic takes);
- **ROS 1 -> ROS 2**: the same publisher -> the bridge -> a Zenoh subscriber on rmw_zenoh's data key (what an
  rmw_zenoh node receives; the stamp is read from the CDR body, nothing else is decoded);
- **ROS 2 -> ROS 1**: CDR bodies put on Zenoh with rmw_zenoh's attachment under an ``MP`` token -> the bridge ->
  an mrosd subscriber.

Printed: the receive rate as a fraction of the send rate, median and p99 one-way latency (same host, same
clock), and the bridge's CPU seconds per forwarded MB. Usage: ``python -m bench ros2 [--seconds 3]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
#: (label, body bytes, image width x height, send rate Hz)
CASES = [("1 KB", 1024, 1000.0), ("1 MB", 1_000_000, 100.0), ("6 MB 1080p", 1920 * 1080 * 3, 30.0)]
TICK = os.sysconf("SC_CLK_TCK")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _start(argv: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=ROOT)


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def _image_body(size: int) -> bytearray:
    """A ROS 1 sensor_msgs/Image of about ``size`` bytes of rgb8 data; the stamp is at bytes 4..12."""
    from mrosd.msg import get_message_class

    image = get_message_class("sensor_msgs/Image")
    width = 1920 if size >= 1920 * 3 else max(1, size // 3)
    height = max(1, size // (width * 3))
    return bytearray(
        image(height=height, width=width, encoding="rgb8", step=width * 3, data=bytes(width * height * 3)).serialize()
    )


class Window:
    """Arrivals counted with their one-way latency (ms) from the stamp in the body."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.reset()

    def reset(self) -> None:
        with self.lock:
            self.lat: list[float] = []
            self.nbytes = 0

    def arrive(self, sec: int, nsec: int, size: int) -> None:
        now = time.time_ns()
        with self.lock:
            self.lat.append((now - (sec * 1_000_000_000 + nsec)) / 1e6)
            self.nbytes += size

    def row(self, label: str, sent: int, seconds: float, cpu: float | None = None) -> str:
        with self.lock:
            n, lat = len(self.lat), sorted(self.lat)
        text = f"  {label:<16} {n / max(sent, 1):6.2f}x of {sent / seconds:7.1f}/s"
        if lat:
            text += f"   latency median {statistics.median(lat):7.2f} ms  p99 {lat[int(0.99 * (len(lat) - 1))]:7.2f} ms"
        if cpu is not None and self.nbytes:
            text += f"   bridge {cpu / (self.nbytes / 1e6) * 1000:6.2f} ms CPU/MB"
        return text


async def _send(publish: Any, body: bytearray, rate: float, seconds: float) -> int:
    """Publish ``body`` at ``rate`` for ``seconds`` (stamping each), on a fixed schedule; returns the count."""
    period, sent = 1.0 / rate, 0
    start = time.monotonic()
    while (now := time.monotonic()) - start < seconds:
        due = start + sent * period
        if now < due:
            await asyncio.sleep(due - now)
            continue
        t = time.time_ns()
        struct.pack_into("<II", body, 4, t // 1_000_000_000, t % 1_000_000_000)
        done = publish(bytes(body))  # a copy: the publisher may still hold the previous one
        if done is not None:
            await done  # a Zenoh put, on a thread: the loop keeps receiving meanwhile
        sent += 1
    await asyncio.sleep(0.3)  # the last ones arrive
    return sent


async def run(seconds: float) -> None:
    import zenoh

    import mrosd
    from mrosd.fleet.raw import raw_message_class
    from mrosd.msg import get_message_class
    from mrosd.ros2.attachment import encode_attachment, gid_of
    from mrosd.ros2.keys import EntityKind, LivelinessToken, Qos, data_key, dds_type_name
    from mrosd.ros2.types import TypeMapper
    from mrosd.tcpros.subscriber import AnyMsg

    image = get_message_class("sensor_msgs/Image")
    raw = raw_message_class("sensor_msgs/Image", image._md5sum, str(image._full_text))
    mapper = TypeMapper()
    mapping = mapper.mapping("sensor_msgs/Image")
    master_port, zenoh_port = _free_port(), _free_port()
    master = f"http://127.0.0.1:{master_port}"
    env = {**os.environ, "ROS_MASTER_URI": master, "ROS_IP": "127.0.0.1"}
    procs = [_start(["rosmaster", "--core", "-p", str(master_port)], env)]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{zenoh_port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    router = zenoh.open(conf)
    try:
        await asyncio.sleep(1.0)
        bridge = _start(
            [str(Path(sys.executable).parent / "mros"), "ros2", "bridge", "--to-ros2", "/bench_out", "--from-ros2",
             "/bench_back", "--connect", f"tcp/127.0.0.1:{zenoh_port}", "--domain-id", "0"],
            env,
        )  # fmt: skip
        procs.append(bridge)
        async with mrosd.Node("bench_ros2", master_uri=master, argv=[], rosout=False, logger_services=False) as node:
            pub = await node.advertise("/bench_out", raw, queue_size=16)
            for label, size, rate in CASES:
                body = _image_body(size)
                print(f"{label} ({len(body)} bytes) at {rate:.0f} Hz", flush=True)
                # TCPROS: publisher -> subscriber
                win = Window()
                sub = await node.subscribe(
                    "/bench_out",
                    AnyMsg,
                    callback=lambda m, w=win: w.arrive(*struct.unpack_from("<II", m.data, 4), len(m.data)),
                    queue_size=16,
                )
                await pub.wait_for_subscribers(1, 30)
                await _send(pub.publish_serialized, bytearray(body), min(rate, 20), 0.5)  # connected and warm
                win.reset()
                sent = await _send(pub.publish_serialized, body, rate, seconds)
                print(win.row("TCPROS", sent, seconds), flush=True)
                await sub.aclose()
                # ROS 1 -> ROS 2: publisher -> bridge -> Zenoh subscriber
                win = Window()
                zsub = router.declare_subscriber(
                    "0/bench_out/**",
                    lambda s, w=win: w.arrive(*struct.unpack_from("<iI", s.payload.to_bytes()[:12], 4), len(s.payload)),
                )
                deadline = time.monotonic() + 30
                while not win.lat and time.monotonic() < deadline:  # the bridge has subscribed and mapped
                    await _send(pub.publish_serialized, body, 10, 0.2)
                win.reset()
                cpu0 = _cpu_seconds(bridge.pid)
                sent = await _send(pub.publish_serialized, body, rate, seconds)
                print(win.row("ROS 1 -> ROS 2", sent, seconds, _cpu_seconds(bridge.pid) - cpu0), flush=True)
                zsub.undeclare()
                # ROS 2 -> ROS 1: Zenoh publisher with rmw_zenoh's attachment and token -> bridge -> subscriber
                win = Window()
                sub = await node.subscribe(
                    "/bench_back",
                    AnyMsg,
                    callback=lambda m, w=win: w.arrive(*struct.unpack_from("<II", m.data, 4), len(m.data)),
                    queue_size=16,
                )
                cdr = bytearray(mapper.to_cdr(mapping.ros2_type, body))
                token = LivelinessToken(
                    domain_id=0, zid=str(router.zid()), nid="9", id=label.split()[0], kind=EntityKind.PUBLISHER,
                    enclave="/", namespace="/", node="bench_talker", topic="/bench_back",
                    type_name=dds_type_name(mapping.ros2_type), type_hash=mapping.type_hash, qos=Qos(depth=4),
                )  # fmt: skip
                live = router.liveliness().declare_token(token.key())
                zpub = router.declare_publisher(
                    data_key(0, "/bench_back", mapping.ros2_type, mapping.type_hash),
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
                gid, seq = gid_of(token.key()), [0]

                def put_cdr(
                    ros1: bytes, cdr: bytearray = cdr, zpub: Any = zpub, gid: bytes = gid, seq: list[int] = seq
                ) -> Any:
                    cdr[4:12] = ros1[4:12]  # the stamp: ROS 1 bytes 4..12 (after seq) are CDR's (after encapsulation)
                    seq[0] += 1
                    attachment = encode_attachment(seq[0], time.time_ns(), gid)
                    return asyncio.to_thread(zpub.put, bytes(cdr), attachment=attachment)

                deadline = time.monotonic() + 30
                while not win.lat and time.monotonic() < deadline:
                    await _send(put_cdr, body, 10, 0.2)
                win.reset()
                cpu0 = _cpu_seconds(bridge.pid)
                sent = await _send(put_cdr, body, rate, seconds)
                print(win.row("ROS 2 -> ROS 1", sent, seconds, _cpu_seconds(bridge.pid) - cpu0), flush=True)
                zpub.undeclare()
                live.undeclare()
                await sub.aclose()
    finally:
        for proc in reversed(procs):
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
        router.close()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench ros2")
    parser.add_argument("--seconds", type=float, default=3.0, help="measured seconds per size and path")
    args = parser.parse_args(argv)
    if shutil.which("rosmaster") is None:
        print("Debian's rosmaster is not installed: run scripts/install-system-deps.sh", file=sys.stderr)
        return 1
    try:
        import zenoh  # noqa: F401
    except ImportError:
        print("the ros2 bench needs pip install 'mrosd[ros2]'", file=sys.stderr)
        return 1
    asyncio.run(run(args.seconds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
