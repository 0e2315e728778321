"""mrosd's own page (``GET /`` on the Foxglove port) in headless Chromium against a running daemon.

Real publishers: rospy from Debian (under /usr/bin/python3) and an mrosd node, each in its own process. The
test reads back what the page drew (graph nodes, the table's Hz, a plotted value, canvas pixels) and saves a
screenshot of each view under ``$MROSD_SCREENSHOTS`` (default ``bench/out/screenshots/``).
"""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import ROS_PYTHON, Processes, ros_available, ros_env

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
NODE = shutil.which("node")
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))
SHOTS = Path(os.environ.get("MROSD_SCREENSHOTS", ROOT / "bench" / "out" / "screenshots"))

pytestmark = pytest.mark.skipif(
    NODE is None or not (HERE / "node_modules" / "playwright-core").is_dir() or not CHROMIUM.exists(),
    reason="node, chromium or playwright-core missing: scripts/install-system-deps.sh, "
    "then `npm ci --prefix tests/web`",
)

SINE_HZ = 20.0
ROSPY_SINE = f"""
import math, rospy
from std_msgs.msg import Float64
rospy.init_node("rospy_sine")
rospy.set_param("/robot/name", "sine-bot")
rospy.set_param("/robot/arm/joints", 6)
pub = rospy.Publisher("/sine", Float64, queue_size=10)
rate = rospy.Rate({SINE_HZ})
t0 = rospy.get_time()
n = 0
while not rospy.is_shutdown():
    value = math.sin(rospy.get_time() - t0)
    pub.publish(Float64(value))
    n += 1
    if n % 10 == 0:
        rospy.loginfo("sine at %.3f", value)
    if n % 30 == 0:
        rospy.logwarn("sine sample %d", n)
    rate.sleep()
"""

ROSPY_LISTENER = """
import rospy
from std_msgs.msg import Float64
from sensor_msgs.msg import Image
rospy.init_node("rospy_listener")
rospy.Subscriber("/sine", Float64, lambda m: None)
rospy.Subscriber("/camera/image", Image, lambda m: None)
rospy.spin()
"""

#: An mrosd node publishing an rgb8 image (pixel (x, y) = (4x, 4y, 128) mod 256, then shifted by the frame
#: number in blue) at IMAGE_HZ and, when FAST_HZ > 0, a Float64 at FAST_HZ.
MROSD_CAMERA = """
import asyncio, os, sys, time
import mrosd
from mrosd.msg import get_message_class
Image = get_message_class("sensor_msgs/Image")
Float64 = get_message_class("std_msgs/Float64")
W, H, HZ, FAST = (float(a) for a in sys.argv[1:5])
W, H = int(W), int(H)
row = bytearray()
for x in range(W):
    row += bytes((4 * x % 256, 0, 128))
frames = []
for k in range(4):
    buf = bytearray()
    for y in range(H):
        r = bytearray(row)
        r[1::3] = bytes([4 * y % 256]) * W
        r[2::3] = bytes([(128 + 40 * k) % 256]) * W
        buf += r
    frames.append(bytes(buf))
async def main():
    async with mrosd.Node("mrosd_camera", argv=[]) as node:
        cam = await node.advertise("/camera/image", Image)
        fast = await node.advertise("/fast", Float64) if FAST > 0 else None
        async def images():
            n = 0
            start = time.monotonic()
            while True:
                img = Image(height=H, width=W, encoding="rgb8", step=3 * W, data=frames[n % 4])
                await cam.publish(img)
                n += 1
                await asyncio.sleep(max(0.0, start + n / HZ - time.monotonic()))
        async def numbers():
            n = 0
            start = time.monotonic()
            while True:
                for _ in range(10):
                    await fast.publish(Float64(data=float(n % 1000)))
                    n += 1
                await asyncio.sleep(max(0.0, start + n / FAST - time.monotonic()))
        await asyncio.gather(images(), *([numbers()] if fast else []))
asyncio.run(main())
"""


def expected_pixel(x: int, y: int, frame: int) -> tuple[int, int, int]:
    return 4 * x % 256, 4 * y % 256, (128 + 40 * frame) % 256


class Browser:
    """tests/web/page_browser.mjs: one command at a time, its reply awaited (bounded)."""

    def __init__(self, procs: Processes) -> None:
        assert NODE is not None
        self.proc = procs.start([NODE, str(HERE / "page_browser.mjs")], cwd_env(), stdin=subprocess.PIPE)
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self.log: list[dict[str, Any]] = []
        threading.Thread(target=self._read, daemon=True).start()
        self._ids = 0
        self._wait(lambda m: m.get("event") == "ready", 30)

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(json.loads(line))

    def _wait(self, pred: Any, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            try:
                msg = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                raise TimeoutError(f"no reply from the browser; its log: {self.log[-10:]}") from None
            if pred(msg):
                return msg
            self.log.append(msg)

    def do(self, cmd: str, timeout: float = 30.0, **kw: Any) -> Any:
        self._ids += 1
        ident = self._ids
        assert self.proc.stdin is not None
        self.proc.stdin.write((json.dumps({"id": ident, "cmd": cmd, **kw}) + "\n").encode())
        self.proc.stdin.flush()
        msg = self._wait(lambda m: m.get("reply") == ident, timeout)
        if "error" in msg:
            raise AssertionError(f"{cmd}: {msg['error']}")
        return msg.get("result")

    def eval(self, expr: str, tab: int = 0) -> Any:
        return self.do("eval", expr=expr, tab=tab)

    def until(self, expr: str, timeout: float = 20.0, tab: int = 0) -> Any:
        """Poll ``expr`` in the page (of tab ``tab``) until it is truthy."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.eval(expr, tab)
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"page never had {expr!r} (last {value!r}); log: {self.log[-10:]}")
            time.sleep(0.2)

    def shot(self, name: str) -> Path:
        SHOTS.mkdir(parents=True, exist_ok=True)
        path = SHOTS / name
        self.do("shot", path=str(path))
        return path


def cwd_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_"))}


def page_url(status: str) -> str:
    match = re.search(r"foxglove ws://(\S+)/", status)
    assert match, status
    return f"http://{match.group(1)}/"


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.fixture
def running(procs: Processes, tmp_path: Path) -> Iterator[tuple[DaemonRun, str]]:
    # No dead-node sweep: a node that died without unregistering must stay listed until the page's own probe
    # draws it dead (the master's sweep, every 5 s by default, removed it first on a loaded machine).
    config = tmp_path / "mrosd.toml"
    config.write_text("[master]\ncleanup_interval = 0\n")
    run = DaemonRun(procs, tmp_path, "--config", str(config))
    try:
        status = run.ready()
        assert status.startswith("running:"), status
        yield run, page_url(status)
    finally:
        run.close()


def camera(procs: Processes, run: DaemonRun, w: int, h: int, hz: float, fast_hz: float = 0) -> None:
    env = {**cwd_env(), "ROS_MASTER_URI": run.uri, "ROS_HOSTNAME": "127.0.0.1", "PYTHONPATH": os.pathsep.join(sys.path)}
    procs.start(
        [sys.executable, "-c", MROSD_CAMERA, str(w), str(h), str(hz), str(fast_hz)], env, stdout=None, stderr=None
    )


def read_pixels(browser: Browser, points: list[tuple[int, int]]) -> list[list[int]]:
    pts = json.dumps(points)
    return list(
        browser.eval(
            f"(() => {{ const c = document.querySelector('#image'); const ctx = c.getContext('2d');"
            f" return {pts}.map(([x, y]) => Array.from(ctx.getImageData(x, y, 1, 1).data)); }})()"
        )
    )


@pytest.mark.interop
@pytest.mark.skipif(not ros_available(), reason="real ROS 1 (Debian ros_comm) is not installed")
def test_the_page_shows_graph_rates_plot_and_image(
    procs: Processes, tmp_path: Path, running: tuple[DaemonRun, str]
) -> None:
    run, url = running
    import urllib.request

    with urllib.request.urlopen(url, timeout=10) as resp:  # the page itself, as a browser gets it
        assert resp.headers["Content-Type"].startswith("text/html")
    procs.start([ROS_PYTHON, "-c", ROSPY_SINE], ros_env(run.uri, tmp_path), stdout=None, stderr=None)
    procs.start([ROS_PYTHON, "-c", ROSPY_LISTENER], ros_env(run.uri, tmp_path), stdout=None, stderr=None)
    camera(procs, run, 64, 48, 10.0)
    browser = Browser(procs)

    # Graph: both publishers' nodes drawn, the camera's node answers with a pid and host.
    browser.do("goto", url=url + "#graph")
    browser.until(
        "['/rospy_sine', '/mrosd_camera', '/rospy_listener']"
        ".every(n => document.querySelector(`#graph g.node[data-name='${n}']`))"
    )
    browser.eval(
        "document.querySelector(\"#graph g.node[data-name='/mrosd_camera']\").dispatchEvent(new Event('click'))"
    )
    info = browser.until("(t => /pid: \\d+/.test(t) && t)(document.querySelector('#node-info').textContent)")
    assert "/camera/image" in info and "host: 127.0.0.1" in info, info
    browser.shot("graph.png")

    # Topics: the rospy topic's Hz (measured by the daemon from bytes seen) within 10 % of the published rate.
    browser.eval("document.querySelector(\"nav button[data-view='topics']\").click()")
    rate_expr = "(r => r && r.dataset.hz)(document.querySelector(\"#topics tr[data-topic='/sine'] td:nth-child(5)\"))"
    browser.until(rate_expr)
    time.sleep(5.5)  # a full 5 s window
    hz = float(browser.eval(rate_expr))
    assert abs(hz - SINE_HZ) <= 0.1 * SINE_HZ, hz
    image_hz = float(
        browser.until("document.querySelector(\"#topics tr[data-topic='/camera/image'] td:nth-child(5)\").dataset.hz")
    )
    assert abs(image_hz - 10.0) <= 1.0, image_hz
    browser.shot("topics.png")

    # Topic view and plot: click the sine's value in the tree; the plotted value changes.
    browser.do("goto", url=url + "#topic=/sine")
    browser.until("document.querySelector(\"#tree .num[data-path='data']\")")
    browser.eval("document.querySelector(\"#tree .num[data-path='data']\").click()")
    first = browser.until("mrosdPage.plot.points.length > 5 && mrosdPage.plot.points.map(p => p[1])")
    # a second more of the sine on the plot (and in the screenshot): SINE_HZ points after ``first``
    browser.until(f"mrosdPage.plot.points.length >= {len(first) + int(SINE_HZ)}")
    later = browser.eval("mrosdPage.plot.points.map(p => p[1])")
    assert len(later) > len(first) and len(set(later)) > 5, later
    assert all(-1.0 <= v <= 1.0 for v in later)
    browser.shot("plot.png")

    # Image: sample pixels of the canvas equal the published ones (any of the 4 frames: blue says which).
    browser.do("goto", url=url + "#topic=/camera/image")
    browser.until("mrosdPage.images.frames > 2")
    points = [(0, 0), (10, 5), (63, 47), (31, 20)]
    got = read_pixels(browser, points)
    frame = [(128 + 40 * k) % 256 for k in range(4)].index(got[0][2])
    assert got == [[*expected_pixel(x, y, frame), 255] for x, y in points]
    browser.shot("image.png")

    # /rosout as a list: rospy's info and warnings; the level filter leaves the warnings.
    browser.do("goto", url=url + "#log")
    browser.until("[...document.querySelectorAll('#log tr')].some(r => r.textContent.includes('sine sample'))")
    browser.until("[...document.querySelectorAll('#log tr')].some(r => r.textContent.includes('sine at'))")
    browser.shot("log.png")
    warn_rows = browser.eval(
        "(() => { const s = document.querySelector('#log-level'); s.value = '4'; s.dispatchEvent(new Event('change'));"
        " return [...document.querySelectorAll('#log tr')].map(r => r.textContent); })()"
    )
    assert warn_rows and all("WARN" in r and "sine sample" in r for r in warn_rows), warn_rows

    browser.do("goto", url=url + "#params")
    params = browser.until("document.querySelector('#params').textContent.includes('sine-bot')")
    assert params
    browser.shot("params.png")

    # A phone-sized screen: the table still fits its width.
    browser.do("viewport", width=390, height=760)
    browser.do("goto", url=url + "#topics")
    time.sleep(2.5)  # the stats restart with the table (their subscriptions were released when it closed)
    browser.until(rate_expr)
    assert browser.eval("document.documentElement.scrollWidth <= 390 + 1")
    browser.shot("phone-topics.png")
    assert not [e for e in browser.log if e.get("event") == "pageerror"], browser.log


def keep_up(procs: Processes, run: DaemonRun, url: str, seconds: float) -> dict[str, float]:
    """The image view on a 30 Hz ~1 MB rgb8 topic (640x546) in one tab and a plot of a 1 kHz Float64 in a
    second tab of the same browser, for ``seconds``: frames drawn, both tabs' JS heap, the daemon's RSS."""
    camera(procs, run, 640, 546, 30.0, 1000.0)
    browser = Browser(procs)
    browser.do("goto", url=url + "#topic=/camera/image")
    plot_tab = browser.do("tab")
    browser.do("goto", url=url + "#topic=/fast", tab=plot_tab)
    browser.until("document.querySelector(\"#tree .num[data-path='data']\")", tab=plot_tab)
    browser.eval("document.querySelector(\"#tree .num[data-path='data']\").click()", tab=plot_tab)
    browser.until("mrosdPage.images.frames > 5", timeout=30)
    browser.until("mrosdPage.plot.points.length > 5", tab=plot_tab)
    heap0 = browser.do("heap")["JSHeapUsedSize"] + browser.do("heap", tab=plot_tab)["JSHeapUsedSize"]
    rss0 = rss_kib(run.proc.pid)
    frames0, t0 = browser.eval("mrosdPage.images.frames"), time.monotonic()
    time.sleep(seconds)
    frames1, t1 = browser.eval("mrosdPage.images.frames"), time.monotonic()
    heap1 = browser.do("heap")["JSHeapUsedSize"] + browser.do("heap", tab=plot_tab)["JSHeapUsedSize"]
    rss1 = rss_kib(run.proc.pid)
    plotted = browser.eval(  # points plotted over the last 5 s (receipt times), per second
        "(p => p.filter(q => q[0] > p.at(-1)[0] - 5).length / 5)(mrosdPage.plot.points)", tab=plot_tab
    )
    result = {
        "fps": (frames1 - frames0) / (t1 - t0),
        "plot_points_per_s": plotted,
        "heap_growth_mib": (heap1 - heap0) / 2**20,
        "rss_growth_mib": (rss1 - rss0) / 1024,
        "heap_mib": heap1 / 2**20,
        "rss_mib": rss1 / 1024,
    }
    print("keep-up", seconds, "s:", json.dumps({k: round(v, 2) for k, v in result.items()}))
    browser.shot("keepup.png")
    return result


def kept_up(result: dict[str, float]) -> None:
    """The Bar: >= 15 frames/s drawn, JS heap and daemon RSS each within 32 MiB of their start."""
    assert result["fps"] >= 15 and result["plot_points_per_s"] >= 10, result
    assert result["heap_growth_mib"] < 32 and result["rss_growth_mib"] < 32, result


def test_the_image_view_keeps_up_with_a_30hz_1mb_image_for_10s(
    procs: Processes, running: tuple[DaemonRun, str]
) -> None:
    run, url = running
    kept_up(keep_up(procs, run, url, 10.0))


@pytest.mark.slow
def test_the_image_view_keeps_up_with_a_30hz_1mb_image_for_60s(
    procs: Processes, running: tuple[DaemonRun, str]
) -> None:
    run, url = running
    kept_up(keep_up(procs, run, url, 60.0))


#: An mrosd node publishing a PNG CompressedImage, a 16UC1 depth image and a LaserScan, each at 5 Hz.
MROSD_SHAPES = """
import asyncio, math, struct, zlib
import mrosd
from mrosd.msg import get_message_class, get_service_class
m = get_message_class
def png(w, h, rgb):
    raw = b"".join(b"\\0" + rgb[y * 3 * w:(y + 1) * 3 * w] for y in range(h))
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
    return (b"\\x89PNG\\r\\n\\x1a\\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
PNG_RGB = b"".join(bytes((17 * x % 256, 60 * y % 256, 200)) for y in range(4) for x in range(8))
depth = b"".join(struct.pack("<H", v) for v in (0, 1000, 2000, 3000, 4000, 5000, 6000, 7000))
async def main():
    async with mrosd.Node("mrosd_shapes", argv=[]) as node:
        p = await node.advertise("/camera/png", m("sensor_msgs/CompressedImage"))
        d = await node.advertise("/camera/depth", m("sensor_msgs/Image"))
        s = await node.advertise("/scan", m("sensor_msgs/LaserScan"))
        SetBool = get_service_class("std_srvs/SetBool")
        await node.advertise_service(
            "/shapes/enable", SetBool, lambda r: SetBool._response_class(success=r.data, message=f"got {r.data}")
        )
        c = await node.advertise("/cloud", m("sensor_msgs/PointCloud2"))
        fields = [m("sensor_msgs/PointField")(name=k, offset=4 * i, datatype=7, count=1) for i, k in enumerate("xyz")]
        pts = b"".join(struct.pack("<fff", math.cos(a / 50) * (1 + a / 400), math.sin(a / 50) * (1 + a / 400), a / 400)
                       for a in range(800))
        cloud = m("sensor_msgs/PointCloud2")(height=1, width=800, fields=fields, point_step=12, row_step=9600,
                                             data=pts, is_dense=True)
        n = 0
        while True:
            await p.publish(m("sensor_msgs/CompressedImage")(format="png", data=png(8, 4, PNG_RGB)))
            await d.publish(m("sensor_msgs/Image")(height=2, width=4, encoding="16UC1", step=8, data=depth))
            ranges = [2.0 + math.sin(i / 10 + n / 5) for i in range(360)]
            await s.publish(m("sensor_msgs/LaserScan")(angle_min=-math.pi, angle_max=math.pi,
                angle_increment=2 * math.pi / 360, range_min=0.1, range_max=10.0, ranges=ranges))
            await c.publish(cloud)
            n += 1
            await asyncio.sleep(0.2)
asyncio.run(main())
"""


def test_the_page_draws_compressed_images_depth_and_scans(procs: Processes, running: tuple[DaemonRun, str]) -> None:
    run, url = running
    env = {**cwd_env(), "ROS_MASTER_URI": run.uri, "ROS_HOSTNAME": "127.0.0.1", "PYTHONPATH": os.pathsep.join(sys.path)}
    procs.start([sys.executable, "-c", MROSD_SHAPES], env, stdout=None, stderr=None)
    browser = Browser(procs)

    # PNG as sent, decoded by the browser: every pixel as published.
    browser.do("goto", url=url + "#topic=/camera/png")
    browser.until("mrosdPage.images.frames > 1")
    points = [(x, y) for y in range(4) for x in range(8)]
    assert read_pixels(browser, points) == [[17 * x % 256, 60 * y % 256, 200, 255] for x, y in points]

    # 16-bit depth as false colour: no reading (0) black, nearest blue-most, farthest red-most.
    browser.do("goto", url=url + "#topic=/camera/depth")
    browser.until("document.querySelector('#image').width === 4 && mrosdPage.images.frames > 1")
    zero, near, far = read_pixels(browser, [(0, 0), (1, 0), (3, 1)])
    assert zero == [0, 0, 0, 255]
    assert near[2] > near[0] and far[0] > far[2], (near, far)

    # A LaserScan from above: drawn, and the canvas is not blank.
    browser.do("goto", url=url + "#topic=/scan")
    browser.until("mrosdPage.images.frames > 1 && document.querySelector('#image').width === 480")
    lit = browser.eval(
        "(() => { const c = document.querySelector('#image'); const d = c.getContext('2d')"
        ".getImageData(0, 0, c.width, c.height).data; let n = 0;"
        " for (let i = 0; i < d.length; i += 4) if (d[i + 2] > 200 && d[i] < 120) n++; return n; })()"
    )
    assert lit > 100, lit
    browser.shot("scan.png")

    # A PointCloud2 from above, coloured by z: every point drawn (800 published).
    browser.do("goto", url=url + "#topic=/cloud")
    browser.until("mrosdPage.images.frames > 1 && document.querySelector('#image').width === 480")
    low, high = browser.eval(  # z from 0 to 2 m: the low end blue, the high end red
        "(() => { const c = document.querySelector('#image'); const d = c.getContext('2d')"
        ".getImageData(0, 0, c.width, c.height).data; let lo = 0, hi = 0;"
        " for (let i = 0; i < d.length; i += 4) { if (d[i + 2] > 150 && d[i] < 100) lo++;"
        " if (d[i] > 150 && d[i + 2] < 100 && d[i + 1] < 120) hi++; } return [lo, hi]; })()"
    )
    assert low > 50 and high > 50, (low, high)
    browser.shot("cloud.png")

    # A node that died without unregistering (its port refuses) is drawn dead in the graph.
    with socket.socket() as gone:
        gone.bind(("127.0.0.1", 0))
        dead_uri = f"http://127.0.0.1:{gone.getsockname()[1]}/"
    import xmlrpc.client

    with xmlrpc.client.ServerProxy(run.uri) as master:
        master.registerPublisher("/ghost", "/ghost_topic", "std_msgs/String", dead_uri)
    browser.do("goto", url=url + "#graph")
    browser.until("document.querySelector(\"#graph g.node.dead[data-name='/ghost']\")")
    assert not browser.eval("document.querySelector(\"#graph g.node.dead[data-name='/mrosd_shapes']\")")
    browser.shot("graph-dead.png")

    # A service called from the form built from its request type (std_srvs/SetBool: one checkbox).
    browser.do("goto", url=url + "#services")
    browser.until("[...document.querySelectorAll('#service-pick option')].some(o => o.value === '/shapes/enable')")
    browser.eval(
        "(() => { const p = document.querySelector('#service-pick'); p.value = '/shapes/enable';"
        " p.dispatchEvent(new Event('change')); document.querySelector('#req-data').checked = true;"
        " document.querySelector('#service-call').click(); })()"
    )
    result = json.loads(browser.until("document.querySelector('#service-result')?.textContent"))
    assert result == {"success": True, "message": "got True"}, result
    browser.shot("service.png")
    assert not [e for e in browser.log if e.get("event") == "pageerror"], browser.log


def test_with_a_token_the_page_connects_only_when_its_url_carries_it(procs: Processes, tmp_path: Path) -> None:
    from tests.integration.daemon.daemonproc import daemon_env

    run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, MROSD_WEB_TOKEN="s3cret"))
    try:
        status = run.ready()
        url = page_url(status)
        browser = Browser(procs)
        browser.do("goto", url=url + "#topics")  # the page itself holds no data: served without the token
        time.sleep(1.0)
        assert browser.eval("document.querySelector('#conn').className") == "bad"
        assert browser.eval("mrosdPage.state.byTopic.size") == 0
        browser.do("goto", url=url + "?token=s3cret#topics")
        browser.until("document.querySelector('#conn').className === 'ok' && mrosdPage.state.byTopic.has('/rosout')")
    finally:
        run.close()
