"""Master benchmark: our master vs Debian's ``rosmaster --core``, both started in this run on free ports.

Same load generator against both (aiohttp with keep-alive, request bodies encoded once; both servers
keep connections alive: rosmaster's handler speaks HTTP/1.1 with a thread per connection):

* latency of registerPublisher, lookupNode, getSystemState, getParam (one client, sequential calls);
* throughput with 1/8/32 concurrent clients (worker subprocesses, a mix of the four calls);
* registration of N nodes x M topics whose subscriber URIs point at dead ports, against the same
  registration without subscribers to notify (is registration slowed by dead nodes?);
* the full daemon's CPU for 1,000 registerPublisher calls with its web part on vs off (the web hub follows
  the graph from the master in-process, so it should cost little; this row needs no rosmaster).

Run: ``python -m bench.master [--quick] [--duration S]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import resource
import statistics
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import aiohttp

from mrosd import backports
from tests.rosenv import Processes, free_port, ros_available, ros_env, start_rosmaster, wait_for_xmlrpc

DEAD_API = "http://127.0.0.1:{port}/"


def body(method: str, *params: Any) -> bytes:
    return xmlrpc.client.dumps(params, method).encode()


def mix_bodies(tag: str) -> list[bytes]:
    """The four benchmarked calls; each worker registers under its own node name."""
    api = f"http://127.0.0.1:9/{tag}"
    return [
        body("registerPublisher", f"/bench_{tag}", f"/bench/{tag}", "std_msgs/String", api),
        body("lookupNode", "/probe", f"/bench_{tag}"),
        body("getSystemState", "/probe"),
        body("getParam", "/probe", "/bench/param"),
    ]


async def post(session: aiohttp.ClientSession, uri: str, data: bytes) -> bytes:
    async with session.post(uri, data=data, headers={"Content-Type": "text/xml"}) as resp:
        out = await resp.read()
    if b"<int>1</int>" not in out[:400] and b"<i4>1</i4>" not in out[:400]:
        raise RuntimeError(f"unexpected reply: {out[:200]!r}")
    return out


# --- worker subprocess: closed-loop clients for a fixed time ------------------------------------


def http_request(uri: str, data: bytes) -> bytes:
    """A complete HTTP/1.1 POST, encoded once and replayed (the cheapest fair client)."""
    host = uri.split("//", 1)[1].rstrip("/")
    return (
        b"POST / HTTP/1.1\r\nHost: %s\r\nContent-Type: text/xml\r\nContent-Length: %d\r\n\r\n"
        % (host.encode(), len(data))
        + data
    )


async def raw_call(
    reader: asyncio.StreamReader, writer: asyncio.StreamWriter, request: bytes, *, check: bool = True
) -> bool:
    """Send one prepared request and read its response; False if the server closed the connection.

    With ``check`` the reply must carry code 1.
    """
    writer.write(request)
    try:
        head = await reader.readuntil(b"\r\n\r\n")
    except asyncio.IncompleteReadError:
        return False
    length = 0
    close = False
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        key = name.strip().lower()
        if key == b"content-length":
            length = int(value)
        elif key == b"connection" and value.strip().lower() == b"close":
            close = True
    payload = await reader.readexactly(length)
    if check and b"<int>1</int>" not in payload[:400] and b"<i4>1</i4>" not in payload[:400]:
        raise RuntimeError(f"unexpected reply: {payload[:200]!r}")
    return not close


class _LoadProtocol(asyncio.Protocol):
    """One closed-loop client connection: send a prepared request, wait for its full response, repeat.

    Kept cheap on purpose (it shares the 2 cores with the server under test): a response normally
    arrives in one ``data_received`` and is checked without copying beyond one slice.
    """

    def __init__(self, requests: list[bytes], done: asyncio.Future[int], offset: int) -> None:
        self.requests = requests
        self.stop_at = 0.0
        self.done = done
        self.k = offset
        self.count = 0
        self.buf = b""
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def start(self, stop_at: float) -> None:
        self.stop_at = stop_at
        self._send()

    def _send(self) -> None:
        assert self.transport is not None
        requests = self.requests
        self.transport.write(requests[self.k % len(requests)])
        self.k += 1

    def data_received(self, data: bytes) -> None:
        buf = self.buf + data if self.buf else data
        while True:
            end = buf.find(b"\r\n\r\n")
            if end < 0:
                break
            at = buf.find(b"Content-Length:", 0, end)
            if at < 0:
                at = buf.lower().find(b"content-length:", 0, end)
            length = int(buf[at + 15 : buf.find(b"\r\n", at, end + 2)])
            stop = end + 4 + length
            if len(buf) < stop:
                break
            ok = buf.find(b"<int>1</int>", end, min(stop, end + 400)) >= 0 or buf.find(b"<i4>1</i4>", end, stop) >= 0
            if not ok:
                raise RuntimeError(f"unexpected reply: {buf[end : end + 200]!r}")
            buf = buf[stop:]
            self.count += 1
            if time.perf_counter() >= self.stop_at:
                assert self.transport is not None
                self.transport.close()
                if not self.done.done():
                    self.done.set_result(self.count)
                break
            self._send()
        self.buf = buf

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.done.done():
            self.done.set_result(self.count)


def _cpu_now() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


async def worker(uri: str, concurrency: int, duration: float, tag: str) -> tuple[int, float]:
    """Closed-loop load: ``concurrency`` kept-alive connections, each one call at a time.

    Returns the calls completed and this process's CPU seconds during the timed window only.
    """
    bodies = mix_bodies(tag)
    requests = [http_request(uri, b) for b in bodies]
    host, port = uri.split("//", 1)[1].rstrip("/").split(":")
    reader, writer = await asyncio.open_connection(host, int(port))
    try:  # register once so lookupNode succeeds, and set the parameter getParam reads
        await raw_call(reader, writer, requests[0])
        await raw_call(reader, writer, http_request(uri, body("setParam", "/probe", "/bench/param", 42)))
    finally:
        writer.close()
    loop = asyncio.get_running_loop()
    futures: list[asyncio.Future[int]] = []
    clients: list[_LoadProtocol] = []
    for i in range(concurrency):
        fut: asyncio.Future[int] = loop.create_future()
        futures.append(fut)
        _, proto = await loop.create_connection(
            lambda fut=fut, i=i: _LoadProtocol(requests, fut, i),  # type: ignore[misc]
            host,
            int(port),
        )
        clients.append(proto)
    cpu0 = _cpu_now()
    stop_at = time.perf_counter() + duration
    for client in clients:
        client.start(stop_at)
    counts = await backports.wait_for(asyncio.gather(*futures), duration + 30)
    return sum(counts), _cpu_now() - cpu0


def throughput(uri: str, clients: int, duration: float, procs_n: int) -> tuple[float, float]:
    """Calls per second with ``clients`` concurrent closed-loop clients spread over ``procs_n`` processes,
    and the load generator's own CPU seconds per call (during the timed window)."""
    procs_n = max(1, min(procs_n, clients))
    per = clients // procs_n
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "bench.master", "--worker", uri, str(per), str(duration), f"w{i}"],
            stdout=subprocess.PIPE,
            text=True,
        )
        for i in range(procs_n)
    ]
    total = 0
    cpu = 0.0
    for p in procs:
        out, _ = p.communicate(timeout=duration + 60)
        count, used = out.split()
        total += int(count)
        cpu += float(used)
    return total / duration, cpu / max(total, 1)


# --- latency and registration (in process) ------------------------------------------------------


async def latency(uri: str, n: int) -> dict[str, float]:
    """Median microseconds per call, sequential, one kept-alive connection (same raw client as throughput)."""
    out: dict[str, float] = {}
    async with aiohttp.ClientSession() as session:
        await post(session, uri, body("setParam", "/probe", "/bench/param", 42))
    host, port = uri.split("//", 1)[1].rstrip("/").split(":")
    reader, writer = await asyncio.open_connection(host, int(port))
    try:
        for i, name in enumerate(["registerPublisher", "lookupNode", "getSystemState", "getParam"]):
            request = http_request(uri, mix_bodies("lat")[i])
            await raw_call(reader, writer, request)
            samples = []
            for _ in range(n):
                t0 = time.perf_counter()
                if not await raw_call(reader, writer, request):
                    writer.close()
                    reader, writer = await asyncio.open_connection(host, int(port))
                samples.append(time.perf_counter() - t0)
            out[name] = statistics.median(samples) * 1e6
    finally:
        writer.close()
    return out


async def registration(uri: str, nodes: int, topics: int, dead: bool, tag: str) -> tuple[float, float]:
    """Seconds to register ``nodes`` x ``topics`` subscribers then publishers (8 concurrent callers).

    With ``dead`` the subscribers register first, at URIs of closed ports, so every publisher
    registration owes them a publisherUpdate; otherwise publishers register first (nothing to send).
    Also returns the median lookupNode latency (us) measured right after, while callbacks drain.
    """
    dead_ports = [free_port() for _ in range(16)]
    subs = [
        body(
            "registerSubscriber",
            f"/{tag}_sub{i}",
            f"/{tag}/n{i}/t{j}",
            "std_msgs/String",
            DEAD_API.format(port=dead_ports[i % len(dead_ports)]),
        )
        for i in range(nodes)
        for j in range(topics)
    ]
    pubs = [
        body("registerPublisher", f"/{tag}_pub{i}", f"/{tag}/n{i}/t{j}", "std_msgs/String", f"http://127.0.0.1:9/{i}")
        for i in range(nodes)
        for j in range(topics)
    ]
    jobs = [http_request(uri, b) for b in (subs + pubs if dead else pubs + subs)]
    host, port = uri.split("//", 1)[1].rstrip("/").split(":")
    it = iter(jobs)

    async def caller() -> None:
        reader, writer = await asyncio.open_connection(host, int(port))
        try:
            for request in it:
                if not await raw_call(reader, writer, request):
                    writer.close()
                    reader, writer = await asyncio.open_connection(host, int(port))
        finally:
            writer.close()

    t0 = time.perf_counter()
    await asyncio.gather(*(caller() for _ in range(8)))
    elapsed = time.perf_counter() - t0
    probe = http_request(uri, body("lookupNode", "/probe", f"/{tag}_pub0"))
    reader, writer = await asyncio.open_connection(host, int(port))
    samples = []
    try:
        for _ in range(50):
            t1 = time.perf_counter()
            # The node may already be gone: our master's graph cleaner drops nodes whose API port is closed.
            await raw_call(reader, writer, probe, check=False)
            samples.append(time.perf_counter() - t1)
    finally:
        writer.close()
    return elapsed, statistics.median(samples) * 1e6


async def register_publishers(uri: str, count: int) -> None:
    """``count`` registerPublisher calls (20 nodes, a topic each) from 8 keep-alive connections."""
    jobs = iter(
        http_request(
            uri, body("registerPublisher", f"/web_{i % 20}", f"/web/t{i}", "std_msgs/String", DEAD_API.format(port=9))
        )
        for i in range(count)
    )
    host, port = uri.split("//", 1)[1].rstrip("/").split(":")

    async def caller() -> None:
        reader, writer = await asyncio.open_connection(host, int(port))
        try:
            for request in jobs:
                if not await raw_call(reader, writer, request):
                    writer.close()
                    reader, writer = await asyncio.open_connection(host, int(port))
        finally:
            writer.close()

    await asyncio.gather(*(caller() for _ in range(8)))


def settle(pid: int, quiet: float = 0.3, limit: float = 20.0) -> float:
    """Wait until process ``pid`` uses no CPU for ``quiet`` seconds (at most ``limit``); its CPU seconds then."""
    deadline = time.monotonic() + limit
    last = cpu_seconds(pid)
    while time.monotonic() < deadline:
        time.sleep(quiet)
        now = cpu_seconds(pid)
        if now - last < 0.01:
            return now
        last = now
    return last


def daemon_registration_cpu(web: bool, count: int) -> float:
    """Daemon CPU seconds (after it settles) for ``count`` registerPublisher calls, web part on or off."""
    from tests.integration.daemon.daemonproc import DaemonRun, daemon_env

    with TemporaryDirectory() as tmp:
        conf = Path(tmp) / "mrosd.toml"
        conf.write_text("[master]\ncleanup_interval = 0\n")  # dead node URIs stay, as in the rows above
        procs = Processes(Path(tmp))
        try:
            env = daemon_env(Path(tmp), MROSD_WEB="1" if web else "0")
            run = DaemonRun(procs, Path(tmp), "--config", str(conf), env=env)
            run.ready()
            pid = run.proc.pid
            before = settle(pid)
            asyncio.run(register_publishers(run.uri, count))
            used = settle(pid) - before
            run.stop()
            run.close()
            return used
        finally:
            procs.close()


def web_cost(count: int = 1000, rounds: int = 2) -> None:
    """Print the daemon's CPU for ``count`` registrations with web off and on (best of ``rounds`` each)."""
    off = min(daemon_registration_cpu(False, count) for _ in range(rounds))
    on = min(daemon_registration_cpu(True, count) for _ in range(rounds))
    print(f"{'metric':48} {'web off':>12} {'web on':>12} {'on/off':>8}")
    print(f"{f'daemon CPU, {count} registerPublisher (s)':48} {off:12.2f} {on:12.2f} {on / off:7.2f}x")


# --- driver -------------------------------------------------------------------------------------


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (Linux /proc), in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def start_ours(procs: Processes) -> str:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    procs.start(
        # --cleanup-interval 0: rosmaster keeps dead nodes, so the sweep (which would probe and remove the dead
        # subscriber URIs registered below) is off for a like-for-like comparison.
        [sys.executable, "-m", "mrosd.master", "--port", str(port), "--cleanup-interval", "0"],
        ros_env(uri, procs.tmp),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc(uri)
    return uri


async def serve_behind_aiohttp(port: int) -> None:
    """The A/B variant: the same ``Master`` (handlers, codec, reply cache) behind aiohttp's low-level server."""
    from aiohttp import web

    from mrosd.master import Master

    master = Master("127.0.0.1", port)  # never started: only its XML-RPC handler is served, by aiohttp
    handler = master._handler
    master.uri = master.api.uri = f"http://127.0.0.1:{port}/"

    async def handle(request: web.BaseRequest) -> web.StreamResponse:
        out = handler.handle(await request.read())
        if type(out) is not bytes:
            out = await out  # type: ignore[misc]
        return web.Response(body=out, content_type="text/xml")

    server = web.Server(handle, access_log=None)
    await asyncio.get_running_loop().create_server(server, "127.0.0.1", port, backlog=1024, reuse_address=True)
    await asyncio.Event().wait()


def start_ours_behind_aiohttp(procs: Processes) -> str:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    procs.start(
        [sys.executable, "-m", "bench.master", "--serve-aiohttp", str(port)],
        ros_env(uri, procs.tmp),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc(uri)
    return uri


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.master")
    parser.add_argument("--quick", action="store_true", help="smaller runs (CI smoke)")
    parser.add_argument("--duration", type=float, default=3.0, help="seconds per throughput run")
    parser.add_argument(
        "--only",
        action="append",
        choices=("latency", "throughput", "registration", "web"),
        help="run only these parts (repeatable; default: all)",
    )
    parser.add_argument(
        "--procs", type=int, default=1, help="load generator processes for the throughput runs (default 1)"
    )
    parser.add_argument(
        "--no-ab", action="store_true", help="skip the A/B run of our master behind aiohttp's low-level server"
    )
    parser.add_argument("--worker", nargs=4, metavar=("URI", "CONC", "DUR", "TAG"), help=argparse.SUPPRESS)
    parser.add_argument("--serve-aiohttp", type=int, metavar="PORT", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.serve_aiohttp:
        import uvloop

        uvloop.run(serve_behind_aiohttp(args.serve_aiohttp))
        return 0
    if args.worker:
        uri, conc, dur, tag = args.worker
        try:
            import uvloop

            uvloop.install()
        except ImportError:  # pragma: no cover
            pass
        count, used = asyncio.run(worker(uri, int(conc), float(dur), tag))
        print(count, used)
        return 0
    parts = set(args.only or ("latency", "throughput", "registration", "web"))
    if "web" in parts:
        web_cost(1000, 1 if args.quick else 2)
        parts.discard("web")
        if not parts:
            return 0
    if not ros_available():
        print("bench.master: Debian rosmaster is not installed; nothing to compare against")
        return 0
    duration = 1.0 if args.quick else args.duration
    nodes, topics = (50, 20) if args.quick else (500, 20)
    lat_n = 100 if args.quick else 500
    with TemporaryDirectory() as tmp:
        procs = Processes(Path(tmp))
        try:
            masters = {"mrosd": start_ours(procs)}
            pids = {"mrosd": procs._procs[-1].pid}  # the helper keeps the Popen objects it started
            masters["rosmaster"] = start_rosmaster(procs)
            pids["rosmaster"] = procs._procs[-1].pid
            if not args.no_ab:
                masters["aiohttp"] = start_ours_behind_aiohttp(procs)
                pids["aiohttp"] = procs._procs[-1].pid
            results: dict[str, dict[str, float]] = {name: {} for name in masters}
            for name, uri in masters.items():
                if "latency" not in parts:
                    break
                for call, us in asyncio.run(latency(uri, lat_n)).items():
                    results[name][f"latency {call} (us)"] = us
            for clients in (1, 8, 32) if "throughput" in parts else ():
                for name, uri in masters.items():
                    cpu0 = cpu_seconds(pids[name])
                    rate, gen_cpu = throughput(uri, clients, duration, args.procs)
                    used = cpu_seconds(pids[name]) - cpu0
                    results[name][f"throughput {clients} clients (calls/s)"] = rate
                    results[name][f"server CPU per call, {clients} clients (us)"] = used / (rate * duration) * 1e6
                    results[name][f"load generator CPU per call, {clients} clients (us)"] = gen_cpu * 1e6
                    if clients == 32:
                        results[name]["server CPU capacity (calls/s per core)"] = rate * duration / used
            for name, uri in masters.items():
                if "registration" not in parts:
                    break
                try:
                    base, _ = asyncio.run(registration(uri, nodes, topics, dead=False, tag="base"))
                    dead, probe = asyncio.run(registration(uri, nodes, topics, dead=True, tag="dead"))
                except RuntimeError as exc:
                    raise RuntimeError(f"{name}: {exc}") from exc
                results[name][f"register {nodes}x{topics} no subscribers (s)"] = base
                results[name][f"register {nodes}x{topics} dead subscribers (s)"] = dead
                results[name]["dead/no-subscriber time ratio"] = dead / base
                results[name]["lookupNode right after (us)"] = probe
        finally:
            procs.close()
    print(f"{'metric':48} {'mrosd':>12} {'rosmaster':>12} {'ratio':>8}")
    for metric, ours in results["mrosd"].items():
        theirs = results["rosmaster"][metric]
        if "calls/s" in metric:
            ratio = ours / theirs if theirs else float("inf")
            note = "x faster"
        elif "ratio" in metric or "generator" in metric:
            ratio, note = float("nan"), ""
        else:
            ratio = theirs / ours if ours else float("inf")
            note = "x faster"
        shown = f"{ratio:7.1f}{note[:1]}" if ratio == ratio else ""
        print(f"{metric:48} {ours:12.1f} {theirs:12.1f} {shown:>8}")
    print(f"(pid {os.getpid()}; ratio = how many times faster mrosd is)")
    if "aiohttp" in results:
        print("\nA/B: the same master, hand-written HTTP layer (mrosd) vs aiohttp's low-level server (llhttp)")
        print(f"{'metric':48} {'mrosd':>12} {'aiohttp':>12} {'ratio':>8}")
        for metric, ours in results["mrosd"].items():
            if "generator" in metric or "registration" in metric or "ratio" in metric:
                continue
            theirs = results["aiohttp"][metric]
            ratio = (ours / theirs if "calls/s" in metric else theirs / ours) if ours and theirs else float("nan")
            print(f"{metric:48} {ours:12.1f} {theirs:12.1f} {ratio:7.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
