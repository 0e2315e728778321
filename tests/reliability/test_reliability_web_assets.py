"""Hostile ``fetchAsset`` requests: what a Foxglove client can make the daemon read, send and hold.

A ROS package is made in tmp_path (``robot_pkg`` with a mesh) and put on the asset search path; next to it are
files that must never be served (a "secret" outside the package, symlinks out of it, a FIFO, a device). The
allow-list is opened to every URI (``assets = ["*"]``) unless the test is about the allow-list itself: the
structural rules must hold whatever an operator writes there. The server runs in the test's loop, so a
blocking read on the loop would stall the test's own ticker (measured).
"""

from __future__ import annotations

import asyncio
import json
import os
import stat
import struct
import threading
import time
from pathlib import Path

import aiohttp
import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.msg.typestore import TypeStore
from mrosd.web.access import AccessPolicy
from mrosd.web.server import WebServer

MiB = 1024 * 1024
MESH = bytes(range(256)) * 64
SECRET = b"secret: never served"


@pytest.fixture
def workspace(tmp_path: Path) -> Path:
    """``<tmp>/ws/robot_pkg`` (a ROS package) and, outside it, a secret the package's symlinks point to."""
    pkg = tmp_path / "ws" / "robot_pkg"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>robot_pkg</name></package>\n")
    (pkg / "meshes" / "base.stl").write_bytes(MESH)
    (tmp_path / "secret.stl").write_bytes(SECRET)
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "secret.stl").write_bytes(SECRET)
    os.symlink(tmp_path / "secret.stl", pkg / "meshes" / "escape.stl")
    os.symlink(tmp_path / "outside", pkg / "meshes" / "outside")
    os.symlink("base.stl", pkg / "meshes" / "alias.stl")  # stays inside: served
    return tmp_path / "ws"


def server_for(master: Master, ws: Path, *, assets: list[str] | None = None, **kw: object) -> WebServer:
    policy = AccessPolicy(assets=["*"] if assets is None else assets)
    store = TypeStore(ros_package_path=str(ws), system_dirs=kw.pop("system_dirs", []))  # type: ignore[arg-type]
    return WebServer(master.uri, port=0, node_host="127.0.0.1", policy=policy, asset_store=store, **kw)  # type: ignore[arg-type]


class AssetClient:
    """fetchAsset out, fetchAssetResponse in: ``{requestId: (status, error, data)}``."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.capabilities: list[str] = []
        self.statuses: list[str] = []

    @classmethod
    async def connect(cls, http: aiohttp.ClientSession, server: WebServer) -> AssetClient:
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"], max_msg_size=0)
        client = cls(ws)
        info = json.loads((await ws.receive(timeout=10)).data)
        client.capabilities = info["capabilities"]
        return client

    async def fetch(self, uri: str, request_id: int) -> None:
        await self.ws.send_str(json.dumps({"op": "fetchAsset", "uri": uri, "requestId": request_id}))

    async def responses(self, count: int, timeout: float = 10.0) -> dict[int, tuple[int, str, bytes]]:
        got: dict[int, tuple[int, str, bytes]] = {}
        async with backports.timeout(timeout):
            while len(got) < count:
                msg = await self.ws.receive()
                if msg.type == aiohttp.WSMsgType.TEXT:
                    data = json.loads(msg.data)
                    if data["op"] == "status":
                        self.statuses.append(data["message"])
                    continue
                assert msg.type == aiohttp.WSMsgType.BINARY, msg
                frame = bytes(msg.data)
                if frame[0] != 4:
                    continue
                _, rid, status, n = struct.unpack_from("<BIBI", frame)
                assert rid not in got, f"request {rid} answered twice"
                got[rid] = (status, frame[10 : 10 + n].decode(), frame[10 + n :])
        return got

    async def one(self, uri: str, timeout: float = 10.0) -> tuple[int, str, bytes]:
        await self.fetch(uri, 7)
        try:
            return (await self.responses(1, timeout))[7]
        except TimeoutError:
            raise AssertionError(f"no fetchAssetResponse to {uri!r}; statuses {self.statuses[-3:]}") from None


def share_doc_files() -> list[str]:
    """Packages with a ``/usr/share/doc/<name>/copyright`` (Debian's, not ROS packages)."""
    return sorted(p.parent.name for p in Path("/usr/share/doc").glob("*/copyright") if p.is_file())


def sparse_file(path: Path, size: int) -> None:
    with open(path, "wb") as f:
        f.truncate(size)  # costs no disk, reads as zeros


def rss() -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmRSS:"))


class LoopLag:
    """The longest gap between two 10 ms ticks of the loop the server runs in (a blocking read shows here)."""

    def __init__(self) -> None:
        self.worst = 0.0
        self._task: asyncio.Task[None] | None = None

    async def _tick(self) -> None:
        last = time.monotonic()
        while True:
            await asyncio.sleep(0.01)
            now = time.monotonic()
            self.worst = max(self.worst, now - last)
            last = now

    def __enter__(self) -> LoopLag:
        self._task = asyncio.get_running_loop().create_task(self._tick())
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()


async def test_a_mesh_in_the_package_is_served_byte_identical(master: Master, workspace: Path) -> None:
    """The one honest request of this file: the positive case the refusals below are measured against."""
    async with server_for(master, workspace) as server, aiohttp.ClientSession() as http:
        client = await AssetClient.connect(http, server)
        assert "assets" in client.capabilities
        assert await client.one("package://robot_pkg/meshes/base.stl") == (0, "", MESH)
        assert await client.one("package://robot_pkg/meshes/alias.stl") == (0, "", MESH)


@pytest.mark.parametrize(
    "uri",
    [
        "package://robot_pkg/../../secret.stl",
        "package://robot_pkg/meshes/../../../secret.stl",
        "package://../secret.stl",
        "package://robot_pkg/meshes/a..b.stl",
        "package://robot_pkg//etc/passwd",
        "package:///etc/passwd",
        "package://robot_pkg/meshes\\..\\..\\..\\secret.stl",
        "package://robot_pkg/meshes/base.stl\x00.png",
        "package://robot_pkg/meshes/escape.stl",
        "package://robot_pkg/meshes/outside/secret.stl",
        "package://robot_pkg/meshes",
        "package://robot_pkg",
        "package://robot_pkg/./meshes/base.stl",
        "file:///etc/passwd",
        "FILE:///etc/passwd",
        "http://127.0.0.1:1/robot.urdf",
        "/etc/passwd",
        "robot_pkg/meshes/base.stl",
        "",
    ],
)
async def test_a_uri_leaving_its_package_is_an_error_reply_that_serves_nothing(
    master: Master, workspace: Path, uri: str
) -> None:
    async with server_for(master, workspace) as server, aiohttp.ClientSession() as http:
        client = await AssetClient.connect(http, server)
        status, error, data = await client.one(uri)
        assert (status, data) == (1, b""), (uri, status, data[:40])
        assert error and SECRET.decode() not in error
        # the connection stays and still serves
        assert (await client.one("package://robot_pkg/meshes/base.stl"))[0] == 0


async def test_file_uris_are_refused_even_when_the_allow_list_names_them(
    master: Master, workspace: Path, tmp_path: Path
) -> None:
    """foxglove_bridge serves file:// when its allow-list matches; mrosd never does (any file the daemon can read)."""
    async with (
        server_for(master, workspace, assets=["file://*", "package://*"]) as server,
        aiohttp.ClientSession() as http,
    ):
        client = await AssetClient.connect(http, server)
        status, error, data = await client.one(f"file://{tmp_path / 'secret.stl'}")
        assert (status, data) == (1, b"") and "package://" in error


async def test_an_unknown_package_and_a_share_dir_that_is_no_package_are_errors(
    master: Master, workspace: Path
) -> None:
    """``/usr/share/doc`` is on the system search path but is no ROS package (no package.xml): not served."""
    docs = share_doc_files()
    async with (
        server_for(master, workspace, system_dirs=["/usr/share"]) as server,
        aiohttp.ClientSession() as http,
    ):
        client = await AssetClient.connect(http, server)
        status, error, _ = await client.one("package://no_such_pkg/meshes/base.stl")
        assert status == 1 and "no_such_pkg" in error
        if docs:
            uri = f"package://doc/{docs[0]}/copyright"
            status, error, data = await client.one(uri)
            assert (status, data) == (1, b""), uri


async def test_a_fifo_in_the_package_is_refused_without_blocking_anything(master: Master, workspace: Path) -> None:
    """Opening a FIFO for reading blocks until a writer comes: it must be refused before, off the loop."""
    fifo = workspace / "robot_pkg" / "meshes" / "pipe.stl"
    os.mkfifo(fifo)
    unblocked = threading.Event()

    def writer_after_deadline() -> None:
        # a safety net for a naive server: a writer arrives after 8 s, so a blocked open returns at last
        if not unblocked.wait(8.0):
            with open(fifo, "wb") as f:
                f.write(b"late")

    safety = threading.Thread(target=writer_after_deadline, daemon=True)
    safety.start()
    try:
        async with server_for(master, workspace) as server, aiohttp.ClientSession() as http:
            client = await AssetClient.connect(http, server)
            with LoopLag() as lag:
                started = time.monotonic()
                status, error, data = await client.one("package://robot_pkg/meshes/pipe.stl", timeout=20)
                took = time.monotonic() - started
            assert (status, data) == (1, b""), (status, data)
            assert "regular file" in error
            assert took < 5.0, took
            assert lag.worst < 1.0, lag.worst
    finally:
        unblocked.set()
        safety.join(timeout=10)


@pytest.mark.skipif(os.geteuid() != 0, reason="mknod of a character device needs root")
async def test_a_device_node_in_the_package_is_refused_before_it_is_opened(master: Master, workspace: Path) -> None:
    """A /dev/zero node inside the package (and a symlink to /dev/zero) would be an endless read."""
    meshes = workspace / "robot_pkg" / "meshes"
    os.mknod(meshes / "zero.stl", stat.S_IFCHR | 0o644, os.makedev(1, 5))
    os.symlink("/dev/zero", meshes / "devzero.stl")
    async with server_for(master, workspace) as server, aiohttp.ClientSession() as http:
        client = await AssetClient.connect(http, server)
        before = rss()
        for name, why in (("zero.stl", "regular file"), ("devzero.stl", "leaves its package")):
            status, error, data = await client.one(f"package://robot_pkg/meshes/{name}")
            assert (status, data) == (1, b"") and why in error, (name, error)
        assert rss() - before < 16 * MiB


async def test_a_file_over_the_size_cap_is_refused_without_reading_it(master: Master, workspace: Path) -> None:
    huge = workspace / "robot_pkg" / "meshes" / "huge.stl"
    sparse_file(huge, 64 * MiB + 1)
    async with server_for(master, workspace, asset_bytes=MiB) as server, aiohttp.ClientSession() as http:
        client = await AssetClient.connect(http, server)
        before = rss()
        with LoopLag() as lag:
            status, error, data = await client.one("package://robot_pkg/meshes/huge.stl")
        assert (status, data) == (1, b"")
        assert "larger than" in error
        assert rss() - before < 16 * MiB
        assert lag.worst < 1.0, lag.worst


async def test_many_fetches_from_a_client_that_does_not_read_cost_a_bound(master: Master, workspace: Path) -> None:
    """300 requests of a 512 KiB mesh at once, nothing read meanwhile: the daemon holds a bound, not 150 MiB;
    each request is answered exactly once; another client is served meanwhile."""
    big = os.urandom(512 * 1024)
    (workspace / "robot_pkg" / "meshes" / "big.stl").write_bytes(big)
    count = 300
    async with server_for(master, workspace) as server, aiohttp.ClientSession() as http:
        greedy = await AssetClient.connect(http, server)
        other = await AssetClient.connect(http, server)
        before = rss()
        peak = before
        with LoopLag() as lag:
            for rid in range(count):
                await greedy.fetch("package://robot_pkg/meshes/big.stl", rid)
            for _ in range(100):  # the server works through them while the greedy client reads nothing
                await asyncio.sleep(0.02)
                peak = max(peak, rss())
            assert await other.one("package://robot_pkg/meshes/base.stl") == (0, "", MESH)
            peak = max(peak, rss())
        assert peak - before < 48 * MiB, f"{(peak - before) / MiB:.1f} MiB held for {count} x 512 KiB requests"
        assert lag.worst < 1.0, lag.worst
        got = await greedy.responses(count, timeout=60)
        served = [rid for rid, (status, _, data) in got.items() if status == 0 and data == big]
        refused = {error for status, error, _ in got.values() if status == 1}
        assert len(served) + sum(1 for s, _, _ in got.values() if s == 1) == count
        assert served, "nothing served"
        assert all("pending" in e for e in refused), refused


async def test_the_allow_list_limits_what_is_served_and_an_empty_one_offers_no_assets(
    master: Master, workspace: Path
) -> None:
    (workspace / "robot_pkg" / "config.yaml").write_text("password: hunter2\n")
    default = AccessPolicy().assets
    async with server_for(master, workspace, assets=default) as server, aiohttp.ClientSession() as http:
        client = await AssetClient.connect(http, server)
        assert (await client.one("package://robot_pkg/meshes/base.stl"))[0] == 0
        status, error, data = await client.one("package://robot_pkg/config.yaml")
        assert (status, data) == (1, b"") and "allow-list" in error
    async with server_for(master, workspace, assets=[]) as server, aiohttp.ClientSession() as http:
        client = await AssetClient.connect(http, server)
        assert "assets" not in client.capabilities


def open_descriptors_of(path: Path) -> int:
    """Descriptors of this process open on ``path`` (the server runs in it)."""
    count = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            count += os.readlink(f"/proc/self/fd/{fd}") == str(path)
        except OSError:
            pass
    return count


async def test_clients_that_leave_mid_fetch_give_back_every_descriptor_and_byte(
    master: Master, workspace: Path
) -> None:
    """20 requests of a 1 MiB mesh, then gone, 20 times over: reads cancelled in their thread close their file
    and give their bytes back to the budget once the thread is done."""
    big = workspace / "robot_pkg" / "meshes" / "big.stl"
    big.write_bytes(os.urandom(MiB))
    async with server_for(master, workspace) as server, aiohttp.ClientSession() as http:
        assets = server.hub.assets
        assert assets is not None
        for attempt in range(20):
            client = await AssetClient.connect(http, server)
            for rid in range(20):
                await client.fetch("package://robot_pkg/meshes/big.stl", rid)
            await asyncio.sleep(0.001 * attempt)  # leave at a different point of the fetch each time
            await client.ws.close()
        async with backports.timeout(10):
            while server.sessions or assets.budget.held or open_descriptors_of(big):  # noqa: ASYNC110 - server state
                await asyncio.sleep(0.01)
        other = await AssetClient.connect(http, server)
        assert await other.one("package://robot_pkg/meshes/base.stl") == (0, "", MESH)
