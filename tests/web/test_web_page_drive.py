"""The page's TF, Actions, Reconfigure and Teleop tabs in headless Chromium against a running daemon (issue 34),
and the daemon's dead-man switch when the browser dies while driving.

One daemon and one browser for the module. Real parties: ``examples/action_server.py`` and
``examples/reconfigure_server.py`` (mrosd), Debian's dynamic_reconfigure TestConfig server and client (rospy),
an mrosd robot (TF broadcasters, a LaserScan, a PointCloud2, a reconfigure server with hostile texts), a rospy
watcher of /cmd_vel and /test_action/result. Screenshots go under ``$MROSD_SCREENSHOTS``.
"""

from __future__ import annotations

import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.rosenv import ROS_PYTHON, Processes, ros_available, ros_env
from tests.web.test_web_page import CHROMIUM, HERE, NODE, ROOT, SHOTS, cwd_env
from tests.web.webdaemon import WebDaemon

pytestmark = [
    pytest.mark.interop,
    pytest.mark.skipif(not ros_available(), reason="real ROS 1 (Debian ros_comm) is not installed"),
    pytest.mark.skipif(
        NODE is None or not (HERE / "node_modules" / "playwright-core").is_dir() or not CHROMIUM.exists(),
        reason="node, chromium or playwright-core missing",
    ),
]

HOSTILE = "<img src=x onerror=window.pwned=1>"
DR_NODE = ROOT / "tests" / "data" / "reconfigure" / "dr_node.py"

#: An mrosd robot: /tf world -> base (moving, 20 Hz), /tf_static base -> laser and a hostile frame, a LaserScan in
#: "laser", a PointCloud2 in "base", and a reconfigure server whose texts are markup.
ROBOT = f"""
import asyncio, math, struct, time
import mrosd
from mrosd.msg import get_message_class as m
from mrosd.tf import StaticTransformBroadcaster, TransformBroadcaster
from mrosd.reconfigure import Description, EnumConstant, GroupSpec, Param, ReconfigureServer
TS, Scan = m("geometry_msgs/TransformStamped"), m("sensor_msgs/LaserScan")
Cloud, Field = m("sensor_msgs/PointCloud2"), m("sensor_msgs/PointField")
HOSTILE = {HOSTILE!r}
def tf(parent, child, x, y, yaw):
    t = TS()
    t.header.stamp = mrosd.Time.now(); t.header.frame_id = parent; t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y = x, y
    t.transform.rotation.z, t.transform.rotation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return t
DESC = Description([GroupSpec("Default", 0, params=[
    Param("speed", "double", 1.0, min=0.0, max=2.0, description=HOSTILE),
    Param("style", "int", 0, min=0, max=1, enum=(EnumConstant(HOSTILE, 0, HOSTILE), EnumConstant("plain", 1))),
]), GroupSpec(HOSTILE, 1, parent=0, params=[Param("label", "str", HOSTILE)])])
async def main():
    async with mrosd.Node("robot", argv=[]) as node, ReconfigureServer(node, DESC, lambda c, l: c):
        dyn = await TransformBroadcaster(node).start()
        static = await StaticTransformBroadcaster(node).start()
        await static.send_transform(tf("base", "laser", 0.5, 0.0, 0.0), tf("base", HOSTILE, -0.5, 0.0, 0.0))
        scan_pub = await node.advertise("/scan", Scan)
        cloud_pub = await node.advertise("/cloud", Cloud)
        fields = [Field(name=k, offset=4 * i, datatype=7, count=1) for i, k in enumerate("xyz")]
        pts = b"".join(struct.pack("<3f", 1.0 + 0.1 * i, 0.5, 0.2) for i in range(10))
        print('{{"up": true}}', flush=True)
        n = 0
        while True:
            await dyn.send_transform(tf("world", "base", 1.0, 2.0, 0.1 * math.sin(n / 20)))
            if n % 4 == 0:
                scan = Scan(angle_min=-1.0, angle_increment=0.1, range_min=0.1, range_max=10.0, ranges=[2.0] * 21)
                scan.header.frame_id = "laser"
                await scan_pub.publish(scan)
                cloud = Cloud(height=1, width=10, fields=fields, point_step=12, row_step=120, data=pts)
                cloud.header.frame_id = "base"
                await cloud_pub.publish(cloud)
            n += 1
            await asyncio.sleep(0.05)
asyncio.run(main())
"""

#: rospy (Debian): every /cmd_vel Twist and every /test_action/result as a JSON line; tf2_ros's static
#: broadcaster puts "world" under "map".
WATCH = """
import json, sys, rospy, tf2_ros
from geometry_msgs.msg import Twist, TransformStamped
from actionlib.msg import TestActionResult
rospy.init_node("watch")
static = tf2_ros.StaticTransformBroadcaster()
t = TransformStamped()
t.header.stamp = rospy.Time.now()
t.header.frame_id, t.child_frame_id = "map", "world"
t.transform.translation.x, t.transform.rotation.w = -3.0, 1.0
static.sendTransform(t)
out = lambda d: (sys.stdout.write(json.dumps(d) + "\\n"), sys.stdout.flush())
rospy.Subscriber("/cmd_vel", Twist, lambda m: out({"x": m.linear.x, "z": m.angular.z, "t": rospy.get_time()}))
rospy.Subscriber("/test_action/result", TestActionResult,
    lambda m: out({"goal": m.status.goal_id.id, "status": m.status.status, "result": m.result.result}))
out({"up": True})
rospy.spin()
"""


class Lines:
    """A process's JSON stdout lines, read by a thread into a queue."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.queue: queue.Queue[dict[str, Any]] = queue.Queue()
        self.seen: list[dict[str, Any]] = []
        assert proc.stdout is not None
        stdout = proc.stdout

        def read() -> None:
            for line in stdout:
                try:
                    self.queue.put(json.loads(line))
                except ValueError:
                    self.queue.put({"text": line.decode(errors="replace").strip()})

        threading.Thread(target=read, daemon=True).start()

    def until(self, pred: Any, timeout: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            try:
                msg = self.queue.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"no such line in {timeout} s; last seen: {self.seen[-5:]}") from None
            self.seen.append(msg)
            if pred(msg):
                return msg

    def once(self, pred: Any, timeout: float = 20.0) -> dict[str, Any]:
        """``until``, or the line already seen."""
        return next((m for m in self.seen if pred(m)), None) or self.until(pred, timeout)

    def drain(self) -> None:
        while True:
            try:
                self.seen.append(self.queue.get_nowait())
            except queue.Empty:
                return


def q(selector: str) -> str:
    """The page's expression for the element ``selector`` names."""
    return f"document.querySelector({json.dumps(selector)})"


class DriveBrowser:
    """tests/web/page_drive_browser.mjs: one command at a time, its reply awaited (bounded)."""

    def __init__(self, procs: Processes) -> None:
        assert NODE is not None
        self.proc = procs.start([NODE, str(HERE / "page_drive_browser.mjs")], cwd_env(), stdin=subprocess.PIPE)
        self.lines = Lines(self.proc)
        self._ids = 0
        self.lines.until(lambda m: m.get("event") == "ready", 30)

    def do(self, cmd: str, timeout: float = 30.0, **kw: Any) -> Any:
        self._ids += 1
        ident = self._ids
        assert self.proc.stdin is not None
        self.proc.stdin.write((json.dumps({"id": ident, "cmd": cmd, **kw}) + "\n").encode())
        self.proc.stdin.flush()
        msg = self.lines.until(lambda m: m.get("reply") == ident, timeout)
        if "error" in msg:
            raise AssertionError(f"{cmd}: {msg['error']}")
        return msg.get("result")

    def eval(self, expr: str) -> Any:
        return self.do("eval", expr=expr)

    def close(self) -> None:
        """Close the browser (node's SIGTERM handling takes seconds): ask, then wait a little for the exit."""
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.write(b'{"cmd": "close"}\n')
            self.proc.stdin.flush()
            self.proc.wait(5)
        except (OSError, subprocess.TimeoutExpired):
            pass

    def until(self, expr: str, timeout: float = 20.0) -> Any:
        deadline = time.monotonic() + timeout
        while True:
            value = self.eval(expr)
            if value:
                return value
            if time.monotonic() > deadline:
                events = [m for m in self.lines.seen if "event" in m][-10:]
                raise AssertionError(f"page never had {expr!r} (last {value!r}); log: {events}")
            time.sleep(0.1)

    def click(self, selector: str) -> None:
        self.eval(f"document.querySelector({json.dumps(selector)}).click()")

    def centre(self, selector: str, fx: float = 0.5, fy: float = 0.5) -> tuple[float, float]:
        r = self.eval(f"(r => [r.left, r.top, r.width, r.height])({q(selector)}.getBoundingClientRect())")
        return r[0] + fx * r[2], r[1] + fy * r[3]

    def choose(self, select: str, value: str) -> None:
        """Pick ``value`` in the ``select`` element as a user does (its change event fires)."""
        self.eval(f"(s => {{ s.value = {json.dumps(value)}; s.dispatchEvent(new Event('change')); }})({q(select)})")

    def shot(self, name: str) -> Path:
        SHOTS.mkdir(parents=True, exist_ok=True)
        self.do("shot", path=str(SHOTS / name))
        return SHOTS / name

    def chromium_pids(self) -> list[int]:
        """The browser's processes (descendants of the node driver)."""
        parent: dict[int, int] = {}
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                continue
            parent[int(stat.parent.name)] = int(fields[1])
        found, frontier = [], [self.proc.pid]
        while frontier:
            pid = frontier.pop()
            kids = [c for c, p in parent.items() if p == pid]
            found += kids
            frontier += kids
        return found


class Robot:
    def __init__(self, procs: Processes, tmp: Path) -> None:
        self.daemon = WebDaemon(procs, tmp, PYTHONUNBUFFERED="1")  # its log read while it runs
        self.url = f"http://127.0.0.1:{self.daemon.foxglove_port}/"
        uri = self.daemon.uri
        ours = {**os.environ, "ROS_MASTER_URI": uri, "ROS_HOSTNAME": "127.0.0.1", "PYTHONPATH": str(ROOT)}
        self.robot = Lines(procs.start([sys.executable, "-c", ROBOT], ours, stderr=None))
        self.actions = procs.start([sys.executable, str(ROOT / "examples" / "action_server.py")], ours, stdout=None)
        self.camera = procs.start([sys.executable, str(ROOT / "examples" / "reconfigure_server.py")], ours)
        self.env = ros_env(uri, tmp)
        self.dr = Lines(procs.start([ROS_PYTHON, str(DR_NODE), "server"], self.env, stderr=subprocess.DEVNULL))
        self.watch = Lines(procs.start([ROS_PYTHON, "-c", WATCH], self.env, stderr=None))
        self.browser = DriveBrowser(procs)

    def debian_get(self, node: str) -> dict[str, Any]:
        done = subprocess.run(
            [ROS_PYTHON, str(DR_NODE), "get", node],
            env=self.env,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
        return result


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    tmp = tmp_path_factory.mktemp("drive")
    procs = Processes(tmp)
    robot = None
    try:
        robot = Robot(procs, tmp)
        yield robot
    finally:
        if robot is not None:
            robot.browser.close()
        procs.close()
        if robot is not None:
            robot.daemon.close()


def test_actions_tab_sends_a_goal_to_its_result_and_cancels_one(robot: Robot) -> None:
    b, watch = robot.browser, robot.watch
    watch.once(lambda m: m.get("up"))
    b.do("goto", url=robot.url + "#actions")
    b.until("[...document.querySelectorAll('#action-pick option')].some(o => o.value === '/test_action')")
    b.choose("#action-pick", "/test_action")
    b.until("document.querySelector('#goal-goal')")
    assert b.eval("document.querySelector('#action-type').textContent") == "actionlib/TestAction"
    # A goal to its end: feedback counts up, the result is 2 x goal.
    b.eval("document.querySelector('#goal-goal').value = '3'")
    b.click("#action-send")
    b.until("document.querySelector('#action-status').dataset.status === 'SUCCEEDED'")
    assert json.loads(b.eval("document.querySelector('#action-result').textContent")) == {"result": 6}
    assert json.loads(b.eval("document.querySelector('#action-feedback').textContent"))["feedback"] >= 1
    goal_id = b.eval("mrosdPage.tabs.actions.goal.id")
    assert goal_id.startswith("/") and goal_id.split("-")[1] == "1", goal_id
    done = watch.until(lambda m: m.get("goal") == goal_id)
    assert (done["status"], done["result"]) == (3, 6)
    # A long goal, cancelled from the page: the server ends it PREEMPTED and the page shows it.
    b.eval("document.querySelector('#goal-goal').value = '50'")
    b.click("#action-send")
    b.until(f"{q('#action-status')}.dataset.status === 'ACTIVE' && {q('#action-feedback')}.textContent")
    b.shot("page-actions-active.png")
    b.click("#action-cancel")
    b.until("document.querySelector('#action-status').dataset.status === 'PREEMPTED'")
    goal_id = b.eval("mrosdPage.tabs.actions.goal.id")
    assert watch.until(lambda m: m.get("goal") == goal_id)["status"] == 2
    b.shot("page-actions-preempted.png")


GROUPS = "[...document.querySelectorAll('#reconf-groups fieldset')].map(f => f.dataset.group).join()"


def _slider_click(b: DriveBrowser, param: str, fraction: float) -> None:
    x, y = b.centre(f"input[data-param='{param}']", fraction, 0.5)
    b.do("mouse", action="move", x=x, y=y)
    b.do("mouse", action="down")
    b.do("mouse", action="up")


def test_reconfigure_tab_moves_sliders_that_dynamic_reconfigure_reads_back(robot: Robot) -> None:
    b = robot.browser
    b.do("goto", url=robot.url + "#reconfigure")
    pick = "document.querySelector('#reconf-pick')"
    b.until(f"[...{pick}.options].map(o => o.value).join() === '/camera,/dr_server,/robot'", timeout=30)
    # mrosd's example server: exposure's slider moved to about 3/4 of [1, 1000]; the server rounds to 5.
    b.choose("#reconf-pick", "/camera")
    b.until("document.querySelector(\"input[data-param='exposure']\")?.dataset.value === '10'")
    assert b.eval("document.querySelector(\"input[data-param='exposure']\").type") == "range"
    assert b.eval("document.querySelector(\"select[data-param='mode']\").options.length") == 3
    assert b.eval(GROUPS) == "Default,Info"
    assert b.eval(f"{q('fieldset[data-group=Info]')}.parentElement.closest('fieldset').dataset.group") == "Default"
    _slider_click(b, "exposure", 0.74)
    answered = b.until("document.querySelector('#reconf-status').dataset.answered")
    exposure = int(answered.split("=")[1])
    assert 600 <= exposure <= 900 and exposure % 5 == 0, answered
    assert b.eval("document.querySelector(\"input[data-param='exposure']\").dataset.value") == str(exposure)
    b.shot("page-reconfigure.png")
    assert robot.debian_get("/camera")["exposure"] == exposure

    # dynamic_reconfigure's own TestConfig server (rospy): int_ in [-10, 10] by its slider, the enum, the groups.
    robot.dr.once(lambda m: m == {"text": "up"}, 30)
    b.choose("#reconf-pick", "/dr_server")
    b.until("document.querySelector(\"input[data-param='int_']\")?.dataset.value === '0'")
    groups = b.eval(GROUPS)
    assert groups == "Default,Group_One,GROUP2,Group3,Upper_Group_2", groups
    enum = b.eval(f"[...{q('select[data-param=int_enum_]')}.options].map(o => o.textContent).join()")
    assert enum == "Small (0),Medium (1),Large (2),ExtraLarge (3)", enum
    b.eval("document.querySelector(\"input[data-param='int_']\").dataset.value = ''")
    _slider_click(b, "int_", 0.85)
    value = int(b.until("document.querySelector(\"input[data-param='int_']\").dataset.value"))
    assert 5 <= value <= 9, value
    b.shot("page-reconfigure-testconfig.png")
    assert robot.debian_get("/dr_server")["int_"] == value

    # Hostile texts (a group name, a description, an enum constant, a default value) stay text.
    b.choose("#reconf-pick", "/robot")
    b.until("document.querySelector(\"input[data-param='label']\")?.dataset.value")
    assert b.eval("document.querySelector(\"input[data-param='label']\").value") == HOSTILE
    assert b.eval("document.querySelector(\"label[for='reconf-speed']\").title") == HOSTILE
    assert HOSTILE in b.eval("document.querySelector('#reconf-groups').textContent")
    assert b.eval("document.querySelectorAll('#reconf-groups img').length") == 0
    assert b.eval("window.pwned === undefined")


def test_tf_tab_shows_the_tree_with_rates_and_draws_frames_scan_and_cloud(robot: Robot) -> None:
    b = robot.browser
    b.do("goto", url=robot.url + "#tf")
    row = "document.querySelector(\"#tf-tree tr[data-frame='{}']\")"
    b.until(f"{row.format('base')} && {row.format('base')}.dataset.rate && {row.format('laser')}")
    cells = b.eval(f"[...{row.format('base')}.children].map(td => td.textContent)")
    assert cells[1] == "world", cells
    laser = b.eval(f"[...{row.format('laser')}.children].map(td => td.textContent)")
    assert laser[1:3] == ["base", "static"], laser
    rate = float(b.eval(f"{row.format('base')}.dataset.rate"))
    assert 14 <= rate <= 26, rate  # broadcast at 20 Hz
    # The tree: map (tf2_ros's static broadcaster, rospy) the root, world under it, base under world, laser under base.
    b.until(f"{row.format('world')} && {row.format('world')}.children[1].textContent === 'map'")
    assert b.eval(f"{row.format('world')}.children[2].textContent") == "static"
    order = b.eval("[...document.querySelectorAll('#tf-tree tbody tr')].map(r => r.dataset.frame)")
    assert order.index("map") < order.index("world") < order.index("base") < order.index("laser"), order
    # Scan (in laser) and cloud (in base) drawn in the fixed frame world: laser sits at (1.5, 2) in world.
    b.eval("document.querySelector('#tf-fixed').value = 'world'")
    for topic in ("/scan", "/cloud"):
        b.until(f"document.querySelector(\"#tf-sensors input[value='{topic}']\")")
        b.eval(f"document.querySelector(\"#tf-sensors input[value='{topic}']\").click()")
    b.until("mrosdPage.tabs.tf.drawn && mrosdPage.tabs.tf.drawn.points === 31")
    drawn = b.eval("mrosdPage.tabs.tf.drawn")
    at = {f["name"]: f["t"] for f in drawn["frames"]}
    assert drawn["fixed"] == "world" and at["world"] == [0, 0, 0]
    assert abs(at["base"][0] - 1.0) < 1e-9 and abs(at["base"][1] - 2.0) < 1e-9
    assert abs(at["laser"][0] - (1.0 + 0.5 * math.cos(drawn_yaw(drawn, "base")))) < 1e-6
    # A hostile frame name is text in the table and on the canvas, never markup.
    assert b.eval(f"{row.format(HOSTILE)}.firstChild.textContent") == HOSTILE
    assert b.eval("document.querySelectorAll('#tf-tree img').length") == 0 and b.eval("window.pwned === undefined")
    b.shot("page-tf.png")


def drawn_yaw(drawn: dict[str, Any], name: str) -> float:
    return float(next(f["yaw"] for f in drawn["frames"] if f["name"] == name))


def _twists(watch: Lines, n: int, moving: bool, timeout: float = 10.0) -> list[dict[str, Any]]:
    got: list[dict[str, Any]] = []
    while len(got) < n:
        got.append(watch.until(lambda m: "x" in m and ((m["x"] != 0 or m["z"] != 0) == moving), timeout))
    return got


def test_teleop_joystick_and_keys_publish_twist_and_zero_on_release_and_tab_close(robot: Robot) -> None:
    b, watch = robot.browser, robot.watch
    watch.once(lambda m: m.get("up"))
    b.do("goto", url=robot.url + "#teleop")
    b.until("mrosdPage.tabs.teleop.chan !== null")
    # The stick dragged up and left: forward and turning left, within the limits (0.5 m/s, 1 rad/s).
    x, y = b.centre("#teleop-pad")
    b.do("mouse", action="move", x=x, y=y)
    b.do("mouse", action="down")
    b.do("mouse", action="move", x=x - 40, y=y - 80, steps=4)
    drive = _twists(watch, 6, True)
    times = [m["t"] for m in drive[-5:]]
    hz = (len(times) - 1) / (times[-1] - times[0])
    assert 7 <= hz <= 13, (hz, drive)
    last = drive[-1]
    assert 0 < last["x"] <= 0.5 and 0 < last["z"] <= 1.0, last
    b.shot("page-teleop.png")
    b.do("mouse", action="up")
    _twists(watch, 1, False)
    # The arrow keys; then the tab closed while a key is held: its pagehide sends the zero.
    b.eval("document.querySelector('#teleop-pad').focus()")
    b.do("key", action="down", key="ArrowUp")
    assert _twists(watch, 2, True)[-1]["x"] == 0.5
    b.do("closetab")
    _twists(watch, 1, False)
    # That zero was the page's (pagehide): its last command was a zero, so the daemon's dead-man stayed quiet.
    time.sleep(0.3)
    assert "dead-man" not in robot.daemon.log()


def test_the_daemon_stops_the_robot_when_the_driving_browser_dies(robot: Robot, tmp_path: Path) -> None:
    procs = Processes(tmp_path)
    watch = robot.watch
    try:
        b = DriveBrowser(procs)
        b.do("goto", url=robot.url + "#teleop")
        b.until("mrosdPage.tabs.teleop.chan !== null")
        b.eval("document.querySelector('#teleop-pad').focus()")
        b.do("key", action="down", key="ArrowLeft")
        assert _twists(watch, 2, True)[-1]["z"] == 1.0
        watch.drain()
        # The browser killed outright: no pagehide, no close frame. Only the daemon can send the zero now.
        for pid in b.chromium_pids():
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        _twists(watch, 1, False)
        deadline = time.monotonic() + 5
        while "dead-man" not in robot.daemon.log() and time.monotonic() < deadline:
            time.sleep(0.05)  # the daemon's line is written right after the zero, by another process
        assert "dead-man" in robot.daemon.log(), (watch.seen[-8:], robot.daemon.log()[-1500:])
        b.close()
    finally:
        procs.close()
