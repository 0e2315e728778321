"""TCPROS benchmark after the mROS paper's section 5.4: /ping -> echo node -> /pong round trips.

For each implementation (mrosd, Debian's rospy, a roscpp node compiled here) an echo node of that
implementation republishes /ping on /pong, and a sender of the same implementation measures the round-trip
time of 200 messages (after 20 warm-up ones) for std_msgs/String of 1 B to 32 KB and for the paper's
Coordinate type (float32 x, y, z; time time). Then throughput: bursts of small Strings (msgs/s) and of 1 MB
and 8 MB sensor_msgs/Image (MB/s, counted on the echoed copies). All against one Debian rosmaster, in one
run; ratios are printed, and a plot of RTT against size goes to bench/out/tcpros_rtt.png.

Usage: ``python -m bench.tcpros [--count 200] [--quick] [--images-only] [--rounds 3]``; the same module is the
mrosd echo/sender process
(``--role echo|ping|burst``). uvloop is used in the mrosd processes when installed.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

from bench.stats import latency_summary

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data" / "tcpros"
OUT = Path(__file__).resolve().parent / "out"
ROS_PYTHON = "/usr/bin/python3"
SIZES = [2**i for i in range(16)]  # 1 B .. 32 KB
SMALL = 16
IMAGES = [(1024 * 1024, 30), (8 * 1024 * 1024, 10)]
BURST_SMALL = 10000


# --- the mrosd echo and sender processes ----------------------------------------------------------


def _classes() -> dict[str, Any]:
    from mrosd.msg import get_message_class, load_type

    return {
        "string": get_message_class("std_msgs/String"),
        "image": get_message_class("sensor_msgs/Image"),
        "coordinate": load_type("mros_bench/Coordinate", (DATA / "msg" / "Coordinate.msg").read_text()),
    }


def _make(kind: str, cls: Any, size: int) -> Any:
    if kind == "string":
        return cls(data="x" * size)
    if kind == "image":
        return cls(height=1, width=size, encoding="mono8", step=size, data=bytes([7]) * size)
    from mrosd.msg import Time

    return cls(x=1.5, y=2.5, z=-3.0, time=Time(7, 8))


def _settle_gc() -> None:
    """Move start-up objects out of the collector's young generations (standard practice for servers).

    Without it a gen-0/1 collection in the middle of a round trip scans every object made at start-up
    (classes, aiohttp, message types) and shows up as multi-millisecond p99 spikes.
    """
    gc.collect()
    gc.freeze()


async def _echo(kind: str) -> None:
    import mrosd

    cls = _classes()[kind]
    async with mrosd.Node(f"mrosd_echo_{os.getpid()}", argv=[]) as node:
        pub = await node.advertise("/pong", cls, queue_size=1000)
        await node.subscribe("/ping", cls, callback=pub.publish_nowait, queue_size=1000)
        _settle_gc()
        print("up", flush=True)
        await node.shutdown_event.wait()


async def _send(mode: str, kind: str, sizes: list[int], n: int) -> None:
    import mrosd

    cls = _classes()[kind]
    loop = asyncio.get_running_loop()
    state = {"received": 0, "last": 0}
    waiter: list[asyncio.Future[None] | None] = [None]
    target = [0]

    def on_pong(_msg: Any) -> None:
        state["received"] += 1
        state["last"] = time.perf_counter_ns()
        fut = waiter[0]
        if fut is not None and state["received"] >= target[0] and not fut.done():
            fut.set_result(None)

    def expire(fut: asyncio.Future[None]) -> None:
        if not fut.done():
            fut.set_exception(TimeoutError())

    async def wait_for(count: int, timeout: float) -> bool:
        if state["received"] >= count:
            return True
        target[0] = count
        fut = waiter[0] = loop.create_future()
        timer = loop.call_later(timeout, expire, fut)
        try:
            await fut
        except TimeoutError:
            return False
        finally:
            timer.cancel()
        return True

    async with mrosd.Node(f"mrosd_{mode}_{os.getpid()}", argv=[]) as node:
        pub = await node.advertise("/ping", cls, queue_size=1000)
        sub = await node.subscribe("/pong", cls, callback=on_pong, queue_size=1000)
        await pub.wait_for_subscribers(1, 30)
        await sub.wait_for_publishers(1, 30)
        _settle_gc()
        for size in sizes:
            msg = _make(kind, cls, size)
            if mode == "ping":
                for _ in range(20):
                    want = state["received"] + 1
                    pub.publish_nowait(msg)
                    if not await wait_for(want, 5.0):
                        sys.exit(3)
                rtts = []
                for _ in range(n):
                    want = state["received"] + 1
                    t0 = time.perf_counter_ns()
                    pub.publish_nowait(msg)
                    if not await wait_for(want, 5.0):
                        sys.exit(3)
                    rtts.append(state["last"] - t0)
                print(f"RTT {size} " + " ".join(map(str, rtts)), flush=True)
            else:
                start = state["received"]
                t0 = time.perf_counter_ns()
                for i in range(n):
                    pub.publish_nowait(msg)
                    if i % 64 == 63:
                        await asyncio.sleep(0)
                before = -1
                while state["received"] != before and state["received"] - start < n:
                    before = state["received"]
                    await wait_for(start + n, 1.0)
                got = state["received"] - start
                print(f"BURST {size} {got} {(state['last'] - t0) / 1e9:.6f}", flush=True)


def _role(args: argparse.Namespace) -> int:
    try:
        import uvloop

        uvloop.install()
    except ImportError:
        pass
    if args.role == "echo":
        asyncio.run(_echo(args.kind))
    else:
        asyncio.run(_send(args.role, args.kind, [int(x) for x in args.sizes.split(",")], args.n))
    return 0


# --- orchestration ---------------------------------------------------------------------------------


class Runner:
    """Starts the master and the echo/sender processes of each implementation; kills them all at the end."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[subprocess.Popen[bytes]] = []
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self.master = f"http://127.0.0.1:{port}/"
        self.start(["rosmaster", "--core", "-p", str(port)], out=subprocess.DEVNULL)
        deadline = time.monotonic() + 20
        while True:
            try:
                with xmlrpc.client.ServerProxy(self.master) as proxy:
                    proxy.getPid("/bench")
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)

    def env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "PYTHONPATH"))}
        env.update(
            ROS_MASTER_URI=self.master,
            ROS_HOSTNAME="127.0.0.1",
            ROS_HOME=str(self.tmp / "ros_home"),
            ROS_LOG_DIR=str(self.tmp / "ros_log"),
            PYTHONUNBUFFERED="1",
        )
        return env

    def start(self, argv: list[str], out: Any = subprocess.PIPE) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            argv, env=self.env() if hasattr(self, "master") else None, stdout=out, stderr=subprocess.DEVNULL,
            cwd=ROOT, start_new_session=True,
        )  # fmt: skip
        self.procs.append(proc)
        return proc

    def stop(self, proc: subprocess.Popen[bytes]) -> None:
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(5)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(5)
        if proc.stdout is not None:
            proc.stdout.close()

    def close(self) -> None:
        for proc in reversed(self.procs):
            self.stop(proc)


def _commands(impl: str, cpp: str | None) -> tuple[list[str], list[str]] | None:
    if impl == "mrosd":
        base = [sys.executable, "-m", "bench.tcpros", "--role"]
        return [*base, "echo"], [*base]
    if impl == "rospy":
        return [ROS_PYTHON, str(DATA / "rospy_node.py"), "echo"], [ROS_PYTHON, str(DATA / "rospy_node.py")]
    if cpp is None:
        return None
    return [cpp, "echo"], [cpp]


def _run_pair(runner: Runner, impl: str, cpp: str | None, mode: str, kind: str, sizes: list[int], n: int) -> list[str]:
    cmds = _commands(impl, cpp)
    if cmds is None:
        return []
    echo_cmd, send_cmd = cmds
    if impl == "mrosd":
        echo = runner.start([*echo_cmd, "--kind", kind])
        sender_argv = [*send_cmd, mode, "--kind", kind, "--sizes", ",".join(map(str, sizes)), "--n", str(n)]
    else:
        echo = runner.start([*echo_cmd, kind])
        sender_argv = [*send_cmd, mode, kind, ",".join(map(str, sizes)), str(n)]
    if impl != "roscpp":
        assert echo.stdout is not None
        echo.stdout.readline()  # "up"
    sender = runner.start(sender_argv)
    try:
        out, _ = sender.communicate(timeout=600)
    finally:
        runner.stop(sender)
        runner.stop(echo)
    return out.decode().splitlines()


def _compile_roscpp(tmp: Path) -> str | None:
    if shutil.which("g++") is None:
        return None
    flags = subprocess.run(
        ["pkg-config", "--cflags", "--libs", "roscpp", "std_msgs", "sensor_msgs"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if flags.returncode != 0:
        return None
    out = tmp / "rosnode_echo"
    build = subprocess.run(
        ["g++", "-O2", "-o", str(out), str(DATA / "rosnode_echo.cpp"), *flags.stdout.split()],
        capture_output=True, check=False,
    )  # fmt: skip
    return str(out) if build.returncode == 0 else None


def _plot(results: dict[str, dict[int, dict[str, float]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for impl, by_size in results.items():
        if by_size:
            xs = sorted(by_size)
            ax.plot(xs, [by_size[x]["median"] for x in xs], marker="o", label=f"{impl} (median)")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("std_msgs/String payload (bytes)")
    ax.set_ylabel("round-trip time (µs)")
    ax.set_title("TCPROS /ping -> echo -> /pong RTT (200 messages per size)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.tcpros", description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=200, help="round trips per size (default 200)")
    parser.add_argument("--quick", action="store_true", help="fewer sizes and smaller bursts")
    parser.add_argument("--impl", default="mrosd,rospy,roscpp", help="comma-separated implementations")
    parser.add_argument("--images-only", action="store_true", help="only the 1 MB / 8 MB image throughput")
    parser.add_argument(
        "--rounds", type=int, default=3, help="image bursts per implementation, interleaved; the median is reported"
    )
    parser.add_argument("--role", choices=["echo", "ping", "burst"], help=argparse.SUPPRESS)
    parser.add_argument("--kind", default="string", help=argparse.SUPPRESS)
    parser.add_argument("--sizes", default="1", help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, default=200, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role:
        return _role(args)
    if shutil.which("rosmaster") is None:
        print("Debian's rosmaster is not installed: run scripts/install-system-deps.sh", file=sys.stderr)
        return 2
    impls = args.impl.split(",")
    sizes = [1, 64, 1024, 32768] if args.quick else SIZES
    burst_small = 2000 if args.quick else BURST_SMALL
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="mrosd-bench-tcpros-") as tmp_name:
        tmp = Path(tmp_name)
        cpp = _compile_roscpp(tmp) if "roscpp" in impls else None
        if "roscpp" in impls and cpp is None:
            print("roscpp: cannot compile the echo node (g++/libroscpp-dev missing); skipped")
        runner = Runner(tmp)
        rtt: dict[str, dict[int, dict[str, float]]] = {i: {} for i in impls}
        coord: dict[str, dict[str, float]] = {}
        small: dict[str, float] = {}
        images: dict[str, dict[int, float]] = {i: {} for i in impls}
        image_runs: dict[str, dict[int, list[float]]] = {i: {size: [] for size, _ in IMAGES} for i in impls}
        try:
            for impl in [] if args.images_only else impls:
                for line in _run_pair(runner, impl, cpp, "ping", "string", sizes, args.count):
                    if line.startswith("RTT "):
                        _, size, *vals = line.split()
                        rtt[impl][int(size)] = latency_summary([int(v) for v in vals])
                if impl != "roscpp":
                    for line in _run_pair(runner, impl, cpp, "ping", "coordinate", [0], args.count):
                        if line.startswith("RTT "):
                            coord[impl] = latency_summary([int(v) for v in line.split()[2:]])
                for line in _run_pair(runner, impl, cpp, "burst", "string", [SMALL], burst_small):
                    if line.startswith("BURST "):
                        _, _, got, secs = line.split()
                        small[impl] = int(got) / float(secs) if float(secs) > 0 else 0.0
            # Large-message throughput is the noisiest figure on a shared machine: rounds interleave the
            # implementations so that a burst of outside load hits them alike, and the median is kept.
            for _ in range(max(1, args.rounds)):
                for impl in impls:
                    for size, n in IMAGES:
                        for line in _run_pair(runner, impl, cpp, "burst", "image", [size], n):
                            if line.startswith("BURST "):
                                _, _, got, secs = line.split()
                                if float(secs) > 0:
                                    image_runs[impl][size].append(int(got) * size / 1e6 / float(secs))
            for impl in impls:
                for size, runs in image_runs[impl].items():
                    if runs:
                        images[impl][size] = statistics.median(runs)
        finally:
            runner.close()
    _report(impls, [] if args.images_only else sizes, rtt, coord, small, images)
    if not args.images_only:
        _plot(rtt, OUT / "tcpros_rtt.png")
        print(f"\nplot: {OUT / 'tcpros_rtt.png'} (bench/out/ is git-ignored: generated files are never committed)")
    return 0


def _median(table: dict[str, dict[str, float]], impl: str) -> float | None:
    return table.get(impl, {}).get("median")


def _ratio(a: float | None, b: float | None) -> str:
    return f"{a / b:6.2f}x" if a and b else "    n/a"


def _report(
    impls: list[str],
    sizes: list[int],
    rtt: dict[str, dict[int, dict[str, float]]],
    coord: dict[str, dict[str, float]],
    small: dict[str, float],
    images: dict[str, dict[int, float]],
) -> None:
    if sizes:
        print("RTT of std_msgs/String over /ping -> echo -> /pong (µs): mean / median / p99 / max")
    for size in sizes:
        cells = []
        for impl in impls:
            s = rtt[impl].get(size)
            cells.append(
                f"{impl} {s['mean']:7.1f} {s['median']:7.1f} {s['p99']:7.1f} {s['max']:8.1f}" if s else f"{impl} n/a"
            )
        ours = rtt.get("mrosd", {}).get(size, {}).get("median")
        py = rtt.get("rospy", {}).get(size, {}).get("median")
        cpp = rtt.get("roscpp", {}).get(size, {}).get("median")
        print(
            f"{size:6d} B | "
            + " | ".join(cells)
            + f" | rospy/mrosd {_ratio(py, ours)} mrosd/roscpp {_ratio(ours, cpp)}"
        )
    if coord:
        print("RTT of Coordinate (µs): " + " | ".join(
            f"{impl} mean {s['mean']:.1f} median {s['median']:.1f} p99 {s['p99']:.1f} max {s['max']:.1f}"
            for impl, s in coord.items()
        ) + f" | rospy/mrosd {_ratio(_median(coord, 'rospy'), _median(coord, 'mrosd'))}")  # fmt: skip
    if small:
        print(f"small-message throughput ({SMALL} B Strings, echoed, msgs/s): " + " | ".join(
            f"{impl} {v:,.0f}" for impl, v in small.items()
        ) + f" | mrosd/rospy {_ratio(small.get('mrosd'), small.get('rospy'))}"
          + f" mrosd/roscpp {_ratio(small.get('mrosd'), small.get('roscpp'))}")  # fmt: skip
    for size, _ in IMAGES:
        vals = {impl: images[impl].get(size) for impl in impls}
        print(f"image throughput {size // (1024 * 1024)} MB (echoed, MB/s, median of rounds): " + " | ".join(
            f"{impl} {v:.1f}" if v else f"{impl} n/a" for impl, v in vals.items()
        ) + f" | mrosd/rospy {_ratio(vals.get('mrosd'), vals.get('rospy'))}"
          + f" mrosd/roscpp {_ratio(vals.get('mrosd'), vals.get('roscpp'))}")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
