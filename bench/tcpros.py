"""TCPROS benchmark after the mROS paper's section 5.4, plus the loads robots carry (images, point clouds).

RTT, as the paper measures it: a sender publishes a 1-byte std_msgs/String on /ping that names a size, the
echo node answers on /pong with a String of that size (1 B to 32 KB in powers of two), and the sender times
200 round trips per size (after 20 warm-up ones). Coordinate (float32 x, y, z; time) is echoed as received.
Every implementation is measured against itself and, as the paper measured one implementation against
another, in mixed pairings (an mrosd sender with a roscpp or rospy echo node and the reverse). Mean, SD,
median, p99 and max are printed, the means in the layout of the paper's Tables 1-3, and box plots like its
Figs. 16/17 go to bench/out/. Then throughput: bursts of small Strings (msgs/s) and echoed 1 MB / 8 MB
sensor_msgs/Image and 1 MB / 4 MB PointCloud2 (MB/s), over TCPROS for every implementation and, as the
``same-host`` row, between two mrosd processes on the shared-memory transport they negotiate. Each burst runs
twice on one connection, for every implementation alike: first on the new connection (what its first messages
cost, buffers and shared memory touched for the first time included), then again on the warm connection (the
transport's throughput, as the RTT figures come after warm-up round trips). With the same-host rows it also
measures what writing memory costs on this machine (fresh shared, fresh private, already touched) and prints
the throughput that each burst on a new shared-memory connection cannot exceed from memory writes alone (the
rings' first slots and the first receive buffers are fresh memory). Finally the RTT
and image rows again beside a CPU-bound neighbour (one busy-loop process), for every implementation in the
same run. All against one Debian rosmaster.

Usage: ``python -m bench.tcpros [--count 200] [--quick] [--images-only] [--rounds 3] [--no-shm] [--no-neighbour]``; the
same module is the mrosd echo/sender process (``--role echo|ping|burst``). uvloop is used in the mrosd
processes when installed.
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
CLOUDS = [(1024 * 1024, 30), (4 * 1024 * 1024, 15)]
BURST_SMALL = 10000
#: (sender, echo node): each implementation against itself, then the mixed pairings.
PAIRINGS = [
    ("mrosd", "mrosd"),
    ("rospy", "rospy"),
    ("roscpp", "roscpp"),
    ("mrosd", "roscpp"),
    ("roscpp", "mrosd"),
    ("mrosd", "rospy"),
    ("rospy", "mrosd"),
]
#: String sizes measured again beside the busy neighbour.
NEIGHBOUR_SIZES = [1, 1024, 32768]
#: The paper's Tables 1 and 2 split the sizes here.
TABLE_SPLIT = 1024


# --- the mrosd echo and sender processes ----------------------------------------------------------


def _classes() -> dict[str, Any]:
    from mrosd.msg import get_message_class, load_type

    string = get_message_class("std_msgs/String")
    return {
        "string": string,
        "mros": string,
        "image": get_message_class("sensor_msgs/Image"),
        "cloud": get_message_class("sensor_msgs/PointCloud2"),
        "coordinate": load_type("mros_bench/Coordinate", (DATA / "msg" / "Coordinate.msg").read_text()),
    }


def _code(size: int) -> int:
    """The mROS ping's one byte: 'A' + log2 of the reply's size (rounded up)."""
    return ord("A") + max(0, size - 1).bit_length()


def _make(kind: str, cls: Any, size: int) -> Any:
    if kind == "mros":
        return cls(data=chr(_code(size)))
    if kind == "cloud":
        from mrosd.msg import get_message_class

        field = get_message_class("sensor_msgs/PointField")
        fields = [field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyzi")]
        width = size // 16
        return cls(height=1, width=width, fields=fields, point_step=16, row_step=16 * width, is_dense=True,
                   data=bytes(size))  # fmt: skip
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
        callback: Any = pub.publish_nowait
        if kind == "mros":
            replies = [cls(data="x" * (1 << code)) for code in range(16)]

            def answer(ping: Any) -> None:
                pub.publish_nowait(replies[ord(ping.data[0]) - ord("A")])

            callback = answer
        await node.subscribe("/ping", cls, callback=callback, queue_size=1000)
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
                for label in ("BURST", "WARM"):  # on the new connection, then again on the warm one
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
                    print(f"{label} {size} {got} {(state['last'] - t0) / 1e9:.6f}", flush=True)


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

    def start(
        self, argv: list[str], out: Any = subprocess.PIPE, extra_env: dict[str, str] | None = None
    ) -> subprocess.Popen[bytes]:
        env = {**self.env(), **(extra_env or {})} if hasattr(self, "master") else None
        proc = subprocess.Popen(
            argv, env=env, stdout=out, stderr=subprocess.DEVNULL, cwd=ROOT, start_new_session=True,
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


#: "mrosd" is our nodes over TCPROS (shared memory off); "same-host" is the same nodes left to negotiate the
#: shared-memory transport they use by default between mrosd processes on one host (docs/shm.md).
IMPL_ENV = {"mrosd": {"MROSD_SHM": "0"}, "same-host": {"MROSD_SHM": "1"}}


def _commands(impl: str, cpp: str | None) -> tuple[list[str], list[str]] | None:
    if impl in IMPL_ENV:
        base = [sys.executable, "-m", "bench.tcpros", "--role"]
        return [*base, "echo"], [*base]
    if impl == "rospy":
        return [ROS_PYTHON, str(DATA / "rospy_node.py"), "echo"], [ROS_PYTHON, str(DATA / "rospy_node.py")]
    if cpp is None:
        return None
    return [cpp, "echo"], [cpp]


def _run_pair(
    runner: Runner, pair: tuple[str, str], cpp: str | None, mode: str, kind: str, sizes: list[int], n: int
) -> list[str]:
    """Run one sender against one echo node (``pair`` = (sender, echo) implementations); the sender's lines."""
    sender_impl, echo_impl = pair
    echo_cmds, send_cmds = _commands(echo_impl, cpp), _commands(sender_impl, cpp)
    if echo_cmds is None or send_cmds is None:
        return []
    echo_cmd, send_cmd = echo_cmds[0], send_cmds[1]
    echo = runner.start(
        [*echo_cmd, "--kind", kind] if echo_impl in IMPL_ENV else [*echo_cmd, kind], extra_env=IMPL_ENV.get(echo_impl)
    )
    if sender_impl in IMPL_ENV:
        sender_argv = [*send_cmd, mode, "--kind", kind, "--sizes", ",".join(map(str, sizes)), "--n", str(n)]
    else:
        sender_argv = [*send_cmd, mode, kind, ",".join(map(str, sizes)), str(n)]
    if echo_impl != "roscpp":
        assert echo.stdout is not None
        echo.stdout.readline()  # "up"
    sender = runner.start(sender_argv, extra_env=IMPL_ENV.get(sender_impl))
    try:
        out, _ = sender.communicate(timeout=600)
    finally:
        runner.stop(sender)
        runner.stop(echo)
    return out.decode().splitlines()


def _rtts(lines: list[str]) -> dict[int, list[int]]:
    return {int(line.split()[1]): [int(v) for v in line.split()[2:]] for line in lines if line.startswith("RTT ")}


def _bursts(lines: list[str], label: str = "BURST") -> list[tuple[int, int, float]]:
    """(size, messages echoed, seconds) of each burst on a new connection, or with ``label="WARM"`` of the same
    burst repeated on the warm connection."""
    out = []
    for line in lines:
        if line.startswith(label + " "):
            _, size, got, secs = line.split()
            out.append((int(size), int(got), float(secs)))
    return out


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


def _label(pair: tuple[str, str]) -> str:
    return pair[0] if pair[0] == pair[1] else f"{pair[0]}->{pair[1]}"


def _box_plots(rtt: dict[str, dict[int, list[int]]], coord: dict[str, list[int]]) -> list[Path]:
    """Box plots like the paper's Fig. 16 (RTT against String size, one panel per pairing) and Fig. 17."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    labels = [label for label, by_size in rtt.items() if by_size]
    if labels:
        cols = min(3, len(labels))
        rows = (len(labels) + cols - 1) // cols
        fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.6 * rows), sharey=True, squeeze=False)
        for ax, label in zip(axes.flat, labels, strict=False):
            sizes = sorted(rtt[label])
            ax.boxplot([[v / 1000 for v in rtt[label][x]] for x in sizes], showfliers=True, flierprops={"ms": 2})
            ax.set_xticks(range(1, len(sizes) + 1), [str(x) for x in sizes], rotation=90, fontsize=7)
            ax.set_yscale("log")
            ax.set_title(f"sender {label}" if "->" in label else label, fontsize=9)
            ax.set_xlabel("String size (B)", fontsize=8)
            ax.set_ylabel("RTT (µs)", fontsize=8)
            ax.grid(True, axis="y", which="both", alpha=0.3)
        for ax in list(axes.flat)[len(labels) :]:
            ax.set_visible(False)
        fig.suptitle("1-byte /ping -> echo answers with the size -> /pong (mROS paper Fig. 16's method)")
        fig.tight_layout()
        path = OUT / "tcpros_rtt_box.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    if coord:
        fig, ax = plt.subplots(figsize=(7, 4))
        names = list(coord)
        ax.boxplot([[v / 1000 for v in coord[n]] for n in names], showfliers=True, flierprops={"ms": 2})
        ax.set_xticks(range(1, len(names) + 1), names, fontsize=8)
        ax.set_ylabel("RTT (µs)")
        ax.set_title("Coordinate echoed (mROS paper Fig. 17's method)")
        ax.grid(True, axis="y", alpha=0.3)
        fig.tight_layout()
        path = OUT / "tcpros_coordinate_box.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def _busy_loop(runner: Runner) -> subprocess.Popen[bytes]:
    """A CPU-bound neighbour: one process spinning in a loop for as long as it runs."""
    return runner.start([sys.executable, "-c", "while True: pass"], out=subprocess.DEVNULL)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.tcpros", description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=200, help="round trips per size (default 200)")
    parser.add_argument("--quick", action="store_true", help="fewer sizes and smaller bursts")
    parser.add_argument("--impl", default="mrosd,rospy,roscpp", help="comma-separated implementations")
    parser.add_argument("--images-only", action="store_true", help="only the image and point cloud throughput")
    parser.add_argument("--no-mixed", action="store_true", help="only each implementation against itself")
    parser.add_argument("--no-shm", action="store_true", help="skip the same-host (shared memory) image rows")
    parser.add_argument("--no-neighbour", action="store_true", help="skip the runs beside a busy-loop process")
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
    pairs = [p for p in PAIRINGS if p[0] in impls and p[1] in impls and (p[0] == p[1] or not args.no_mixed)]
    selves = [p for p in pairs if p[0] == p[1]]
    sizes = [1, 64, 1024, 32768] if args.quick else SIZES
    burst_small = 2000 if args.quick else BURST_SMALL
    OUT.mkdir(parents=True, exist_ok=True)
    res = Results()
    with tempfile.TemporaryDirectory(prefix="mrosd-bench-tcpros-") as tmp_name:
        tmp = Path(tmp_name)
        cpp = _compile_roscpp(tmp) if "roscpp" in impls else None
        if "roscpp" in impls and cpp is None:
            print("roscpp: cannot compile the echo node (g++/libroscpp-dev missing); skipped")
        runner = Runner(tmp)
        try:
            if not args.images_only:
                for pair in pairs:
                    res.rtt[_label(pair)] = _rtts(_run_pair(runner, pair, cpp, "ping", "mros", sizes, args.count))
                    if "roscpp" not in pair:  # the roscpp node has no Coordinate type compiled in
                        coord = _rtts(_run_pair(runner, pair, cpp, "ping", "coordinate", [0], args.count))
                        if coord:
                            res.coord[_label(pair)] = coord[0]
                for pair in selves:
                    lines = _run_pair(runner, pair, cpp, "burst", "string", [SMALL], burst_small)
                    for _, count, secs in _bursts(lines):
                        res.small[pair[0]] = count / secs if secs > 0 else 0.0
            # images and point clouds also between two mrosd processes on shared memory (the same-host row)
            large = selves + ([("same-host", "same-host")] if "mrosd" in impls and not args.no_shm else [])
            if ("same-host", "same-host") in large:
                res.memory = _memory_costs()
            _throughput(runner, large, cpp, max(1, args.rounds), res.large, res.warm_large)
            if not args.no_neighbour:
                busy = _busy_loop(runner)
                try:
                    for pair in [] if args.images_only else selves:
                        res.busy_rtt[pair[0]] = _rtts(
                            _run_pair(runner, pair, cpp, "ping", "mros", NEIGHBOUR_SIZES, args.count)
                        )
                    _throughput(runner, selves, cpp, 1, res.busy_large, res.busy_warm_large, kinds=("image",))
                finally:
                    runner.stop(busy)
        finally:
            runner.close()
    _report(impls + ([] if args.no_shm or "mrosd" not in impls else ["same-host"]), res)
    if not args.images_only:
        written = _box_plots(res.rtt, res.coord)
        print(f"\nplots: {', '.join(map(str, written))} (bench/out/ is git-ignored: never committed)")
    return 0


class Results:
    """Everything one run measured (raw samples in ns, throughputs in msgs/s or MB/s)."""

    def __init__(self) -> None:
        self.rtt: dict[str, dict[int, list[int]]] = {}
        self.coord: dict[str, list[int]] = {}
        self.small: dict[str, float] = {}
        #: (kind, size) -> implementation -> MB/s (median of rounds)
        self.large: dict[tuple[str, int], dict[str, float]] = {}
        #: the same bursts repeated on the warm connection
        self.warm_large: dict[tuple[str, int], dict[str, float]] = {}
        self.busy_rtt: dict[str, dict[int, list[int]]] = {}
        self.busy_large: dict[tuple[str, int], dict[str, float]] = {}
        self.busy_warm_large: dict[tuple[str, int], dict[str, float]] = {}
        #: this machine's cost of memory, ms per MB (``_memory_costs``)
        self.memory: dict[str, float] = {}


def _throughput(
    runner: Runner,
    selves: list[tuple[str, str]],
    cpp: str | None,
    rounds: int,
    into: dict[tuple[str, int], dict[str, float]],
    warm: dict[tuple[str, int], dict[str, float]],
    kinds: tuple[str, ...] = ("image", "cloud"),
) -> None:
    """Echoed large-message bursts, each on a new connection (``into``) and then again on that connection once
    it is warm (``warm``). Rounds interleave the implementations so that a burst of outside load hits them alike
    (large-message throughput is the noisiest figure on a shared machine); the median is kept."""
    runs: dict[tuple[str, int], dict[str, list[float]]] = {}
    warm_runs: dict[tuple[str, int], dict[str, list[float]]] = {}
    for _ in range(rounds):
        for pair in selves:
            for kind in kinds:
                for size, n in IMAGES if kind == "image" else CLOUDS:
                    lines = _run_pair(runner, pair, cpp, "burst", kind, [size], n)
                    for label, table in (("BURST", runs), ("WARM", warm_runs)):
                        for got_size, got, secs in _bursts(lines, label):
                            if secs > 0:
                                table.setdefault((kind, got_size), {}).setdefault(pair[0], []).append(
                                    got * got_size / 1e6 / secs
                                )
    for table, out in ((runs, into), (warm_runs, warm)):
        for key, by_impl in table.items():
            out[key] = {impl: statistics.median(values) for impl, values in by_impl.items()}


def _ratio(a: float | None, b: float | None) -> str:
    return f"{a / b:5.2f}x" if a and b else "  n/a"


def _paper_table(title: str, labels: list[str], sizes: list[int], rtt: dict[str, dict[int, list[int]]]) -> None:
    """Means in the layout of the mROS paper's Tables 1 and 2 (rows: implementations, columns: sizes)."""
    if not sizes:
        return
    print(title)
    print(f"{'':>16}" + "".join(f"{_size(x):>9}" for x in sizes))
    for label in labels:
        cells = []
        for x in sizes:
            values = rtt.get(label, {}).get(x)
            cells.append(f"{latency_summary(values)['mean']:9.1f}" if values else f"{'n/a':>9}")
        print(f"{label:>16}" + "".join(cells))


def _size(x: int) -> str:
    return f"{x // 1024} KB" if x >= 1024 else f"{x} B"


def _stat_line(s: dict[str, float]) -> str:
    return f"{s['mean']:8.1f} {s['sd']:7.1f} {s['median']:8.1f} {s['p99']:8.1f} {s['max']:9.1f}"


def _memory_costs(mb: int = 64, repeats: int = 3) -> dict[str, float]:
    """ms per MB, medians of ``repeats``: the first write into fresh shared memory (a memfd, as a ring's slots),
    into fresh private memory (as a receive buffer), and a write into memory already touched."""
    import mmap

    size = mb << 20
    src = b"\x5a" * size
    costs: dict[str, list[float]] = {"fresh shared": [], "fresh private": [], "warm": []}
    for _ in range(repeats):
        fd = os.memfd_create("mrosd-bench")
        try:
            os.ftruncate(fd, size)
            with mmap.mmap(fd, size) as shared:
                t0 = time.perf_counter()
                shared[:] = src
                t1 = time.perf_counter()
                shared[:] = src
                t2 = time.perf_counter()
        finally:
            os.close(fd)
        costs["fresh shared"].append((t1 - t0) * 1e3 / mb)
        costs["warm"].append((t2 - t1) * 1e3 / mb)
        with mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS) as private:
            t0 = time.perf_counter()
            private[:] = src
            costs["fresh private"].append((time.perf_counter() - t0) * 1e3 / mb)
    return {what: statistics.median(values) for what, values in costs.items()}


def _new_connection_ceiling(memory: dict[str, float], size: int, n: int) -> float:
    """MB/s that an echoed burst of ``n`` messages of ``size`` bytes on a new shared-memory connection cannot
    exceed here, counting memory writes alone: each process writes every message once into its ring (at least
    the ring's first ``MIN_SLOTS`` slots are fresh; counting no more keeps this an upper bound) and copies every
    message it receives out into its own buffer (the first one fresh); the two processes work in parallel at
    best."""
    from mrosd.shm.publisher import MIN_SLOTS

    mb = size / (1 << 20)
    fresh_slots = min(n, MIN_SLOTS)
    ms = mb * (
        fresh_slots * memory["fresh shared"] + memory["fresh private"] + (2 * n - fresh_slots - 1) * memory["warm"]
    )
    return n * size / 1e6 / (ms / 1e3)


def _report(impls: list[str], res: Results) -> None:
    labels = [label for label in res.rtt if res.rtt[label]]
    sizes = sorted({x for by_size in res.rtt.values() for x in by_size})
    _paper_table("Table 1 layout: mean RTT (µs), 1 B-512 B", labels, [x for x in sizes if x < TABLE_SPLIT], res.rtt)
    _paper_table("Table 2 layout: mean RTT (µs), 1 KB-32 KB", labels, [x for x in sizes if x >= TABLE_SPLIT], res.rtt)
    if res.coord:
        print("Table 3 layout: Coordinate RTT (µs)      mean      SD   median      p99       max")
        for label, values in res.coord.items():
            print(f"{label:>36} {_stat_line(latency_summary(values))}")
    if sizes:
        print(
            "RTT per size (µs)          mean      SD   median      p99       max   | medians: rospy/mrosd, mrosd/roscpp"
        )
    for x in sizes:
        med = {}
        for label in labels:
            samples = res.rtt[label].get(x)
            if samples:
                s = latency_summary(samples)
                med[label] = s["median"]
                print(f"{_size(x):>7} {label:>16} {_stat_line(s)}")
        ours, py, cpp = med.get("mrosd"), med.get("rospy"), med.get("roscpp")
        print(f"{'':>7} {'':>16} {'':>45}   | {_ratio(py, ours):>11} {_ratio(ours, cpp):>12}")
    if res.small:
        print(f"small-message throughput ({SMALL} B Strings, echoed, msgs/s): " + " | ".join(
            f"{impl} {v:,.0f}" for impl, v in res.small.items()
        ) + f" | mrosd/rospy {_ratio(res.small.get('mrosd'), res.small.get('rospy'))}"
          + f" mrosd/roscpp {_ratio(res.small.get('mrosd'), res.small.get('roscpp'))}")  # fmt: skip
    for title, table, how in (
        ("", res.large, "echoed"),
        ("", res.warm_large, "echoed on a warm connection"),
        ("beside a busy-loop process: ", res.busy_large, "echoed"),
        ("beside a busy-loop process: ", res.busy_warm_large, "echoed on a warm connection"),
    ):
        for (kind, size), vals in sorted(table.items()):
            name = f"{title}{'image' if kind == 'image' else 'PointCloud2'}"
            print(f"{name} throughput {size // (1024 * 1024)} MB ({how}, MB/s, median of rounds): " + " | ".join(
                f"{impl} {vals[impl]:.1f}" if vals.get(impl) else f"{impl} n/a" for impl in impls
            ) + f" | mrosd/rospy {_ratio(vals.get('mrosd'), vals.get('rospy'))}"
              + f" mrosd/roscpp {_ratio(vals.get('mrosd'), vals.get('roscpp'))}"
              + (f" same-host/roscpp {_ratio(vals.get('same-host'), vals.get('roscpp'))}"
                 if "same-host" in vals else ""))  # fmt: skip
    if res.memory:
        print("memory here (ms per MB, written with one copy): " + ", ".join(
            f"{what} {ms:.3f}" for what, ms in res.memory.items()
        ))  # fmt: skip
        for msg_kind, bursts in (("image", IMAGES), ("cloud", CLOUDS)):
            for size, n in bursts:
                cpp = res.large.get((msg_kind, size), {}).get("roscpp")
                ceiling = _new_connection_ceiling(res.memory, size, n)
                name = "image" if msg_kind == "image" else "PointCloud2"
                print(
                    f"{name} {size // (1024 * 1024)} MB x {n}, same-host on a new connection,"
                    f" ceiling from memory writes alone: {ceiling:.0f} MB/s"
                    + (f" = {_ratio(ceiling, cpp)} roscpp" if cpp else "")
                )
    if res.busy_rtt:
        print("beside a busy-loop process: RTT median (µs), and idle -> busy")
        for x in NEIGHBOUR_SIZES:
            cells = []
            for impl, by_size in res.busy_rtt.items():
                if by_size.get(x):
                    busy = latency_summary(by_size[x])["median"]
                    idle_values = res.rtt.get(impl, {}).get(x)
                    idle = f"{latency_summary(idle_values)['median']:.1f} -> " if idle_values else ""
                    cells.append(f"{impl} {idle}{busy:.1f}")
            print(f"{_size(x):>7} | " + " | ".join(cells))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
